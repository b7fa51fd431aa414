"""The robot on MJX: a differential-drive base that collides with walls and furniture.

The robot is added to a world's MjSpec: slide joints in x and y and a hinge about z, with
velocity actuators on each. A differential drive has no lateral motion, so the commanded
(v, w) becomes the world-frame velocity (v cos yaw, v sin yaw, w); contacts may still push
the body sideways along a wall (as a real base skids). The collision body is a sphere (MJX
has no cylinder-box collision) is a sphere ``skin`` larger than the robot's plan radius.
The robot only cares about footprints (as the free-space map does), so every box that
reaches below the robot's height enters the physics model as a prism extruded from the
floor to 1 m, and the sphere rides at 0.5 m: each contact is horizontal, an exact 2D
disc-against-footprint collision (a sphere meeting a low board with its curved bottom would
ride over it, since z is not free to move). The floor is not in the physics model. Only robot-vs-static pairs collide and MJX keeps
the nearest few pairs (docs/performance.md: the difference between 1k and 60k steps/s).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from rosmeery_jax.sim.mjx import mjx
from rosmeery_jax.world import World

PROXY_HALF_HEIGHT = 0.5


@dataclass(frozen=True)
class RobotConfig:
    """Platform parameters (docs/robot.md). Body about 0.4 x 0.35 m: a disc of radius
    0.2 m in plan. Limits 1.0 m/s and 3.0 rad/s (the original navigation capped speed at
    0.12 m/s; set ``max_speed`` for that)."""

    radius: float = 0.2
    height: float = 0.5  # boxes reaching below this block the robot (as in the free-space map)
    mass: float = 10.0
    max_speed: float = 1.0
    max_turn_rate: float = 3.0
    control_dt: float = 0.1  # 10 Hz
    substeps: int = 5  # physics dt = 0.02 s
    kv_lin: float = 200.0
    kv_yaw: float = 4.0
    skin: float = 0.02  # the collision sphere is this much larger than the body: at 1 m/s a
    # 0.02 s substep moves 2 cm, and MJX sees a contact only once it penetrates (it ignores
    # geom margins for sphere-box), so the skin absorbs that overshoot
    solver_iterations: int = 4  # constraint solver and line-search iterations per substep
    line_search_iterations: int = 6
    # (2 substeps, a 5 cm skin and 2 / 3 iterations cost a third of the physics time with no
    # penetration, but moved the paper evaluation beyond seed noise: docs/performance.md)
    max_pairs: int = 6  # robot-box pairs MJX collides per substep, nearest first
    near_proxies: int = 16  # proxies MJX sees in one control step: the nearest at its start
    # (0: all). They always held every substep's max_pairs nearest (docs/performance.md),
    # and MJX's per-substep work grows with the proxies it holds
    max_piece: float = 1.0  # collision proxies are split into pieces no longer than this
    max_force: float = 60.0  # N per axis: 6 m/s^2 for the 10 kg base, and it keeps
    # contact forces (hence soft-contact penetration) to millimetres when pushing a wall


FAR = 1e4  # where padding proxies stand: never among the nearest pairs MJX keeps


def proxy_boxes(world: World, cfg: RobotConfig) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(centre, half size, yaw) of the collision proxies: every box that reaches below the
    robot's height, split into pieces and extruded to a prism spanning the sphere's equator."""
    s = world.scene
    out = []
    for g in np.flatnonzero(s.center[:, 2] - s.half[:, 2] < cfg.height):
        for center, half in _pieces(s.center[g], s.half[g], float(s.yaw[g]), cfg.max_piece):
            center[2], half[2] = PROXY_HALF_HEIGHT, PROXY_HALF_HEIGHT  # every contact is horizontal
            out.append((center, half, float(s.yaw[g])))
    return out


def robot_model(world: World, cfg: RobotConfig, proxies: int | None = None) -> mujoco.MjModel:
    """The physics model: the robot plus, as world geoms, the static boxes it can touch.

    Sensing uses the raycast scene, so physics needs only collision proxies: every box that
    reaches below the robot's height, directly under the world body (no furniture bodies to
    carry through MJX's kinematics each substep). ``proxies`` pads the proxy count with inert
    boxes far away, so the models of a session's worlds have one structure and stack into
    one batched model (their names are the same for the same reason).
    """
    boxes = proxy_boxes(world, cfg)
    if proxies is not None and proxies < len(boxes):
        raise ValueError(f"{world.name}: {len(boxes)} collision proxies, more than the {proxies} padded to")
    return _model(boxes + _far_boxes((proxies or len(boxes)) - len(boxes)), world.spawn, cfg)


def near_model(world: World, cfg: RobotConfig, slots: int) -> mujoco.MjModel:
    """The physics model's structure with ``slots`` proxies, which :class:`Platform` fills
    with the nearest of the world's proxies every control step (the static proxies share
    every field but their geometry)."""
    return _model(_far_boxes(slots), world.spawn, cfg)


def _far_boxes(n: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
    return [(np.array([FAR + 2 * k, FAR, PROXY_HALF_HEIGHT]), np.array([0.5, 0.5, PROXY_HALF_HEIGHT]), 0.0)
            for k in range(n)]


def _model(boxes, spawn, cfg: RobotConfig) -> mujoco.MjModel:
    spec = mujoco.MjSpec()
    spec.modelname = "rosmeery_physics"
    spec.compiler.degree = False
    spec.option.timestep = cfg.control_dt / cfg.substeps
    spec.option.iterations = cfg.solver_iterations
    spec.option.ls_iterations = cfg.line_search_iterations
    spec.add_material(name="static", rgba=[0.7, 0.7, 0.7, 1])  # mjx needs one material
    for center, half, yaw in boxes:
        spec.worldbody.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX, pos=center.tolist(), size=half.tolist(),
            quat=[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)], contype=0, conaffinity=1, material="static")
    sx, sy, syaw = (float(v) for v in spawn)
    body = spec.worldbody.add_body(name="robot", pos=[sx, sy, PROXY_HALF_HEIGHT])
    body.add_joint(name="x", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
    body.add_joint(name="y", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 1, 0])
    body.add_joint(name="yaw", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
    body.add_geom(name="robot", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[cfg.radius + cfg.skin, 0, 0],
                  mass=cfg.mass, contype=1, conaffinity=0, rgba=[0.85, 0.1, 0.1, 1],
                  solref=[0.04, 1.0], solimp=[0.99, 0.999, 0.001, 0.5, 2.0])
    for name, kv in (("x", cfg.kv_lin), ("y", cfg.kv_lin), ("yaw", cfg.kv_yaw)):
        spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT,
                          gaintype=mujoco.mjtGain.mjGAIN_FIXED, gainprm=[kv] + [0] * 9,
                          biastype=mujoco.mjtBias.mjBIAS_AFFINE, biasprm=[0, 0, -kv] + [0] * 7,
                          dyntype=mujoco.mjtDyn.mjDYN_NONE, forcelimited=1,
                          forcerange=[-cfg.max_force, cfg.max_force])
    spec.add_numeric(name="max_contact_points", data=[cfg.max_pairs])
    spec.add_numeric(name="max_geom_pairs", data=[cfg.max_pairs])
    model = spec.compile()
    model.qpos0[:] = [0.0, 0.0, syaw]  # slide joints measure from the body's spawn position
    return model


def _pieces(center, half, yaw, max_len):
    """Split a box along x and y into pieces at most ``max_len`` long.

    MJX keeps the ``max_geom_pairs`` pairs whose bounding spheres are nearest; a 10 m wall has
    a 5 m bounding sphere and would crowd out the chair leg the robot is about to touch.
    """
    nx = max(1, int(np.ceil(2 * half[0] / max_len)))
    ny = max(1, int(np.ceil(2 * half[1] / max_len)))
    c, s = np.cos(yaw), np.sin(yaw)
    ph = np.array([half[0] / nx, half[1] / ny, half[2]], dtype=float)
    for i in range(nx):
        for j in range(ny):
            lx = -half[0] + (2 * i + 1) * ph[0]
            ly = -half[1] + (2 * j + 1) * ph[1]
            yield np.array([center[0] + c * lx - s * ly, center[1] + s * lx + c * ly, center[2]]), ph


# MJX's step, jitted on its own: inside a session's program it is inlined as if called
# directly, and JAX keeps its trace (and its batched form) for every later program of the
# process whose model has the same structure, such as the next session's.
_mjx_step = jax.jit(mjx.step)

# The proxies' per-geom fields (every other geom field is the same for all of them); the
# robot's sphere is the model's last geom.
PROXY_FIELDS = ("geom_pos", "geom_quat", "geom_size", "geom_aabb", "geom_rbound")


class Platform:
    """MJX physics; all methods pure and vmappable over envs. The world enters as data: the
    MJX model and the spawn position (the robot pose (x, y, yaw) is world frame; ``qpos``
    holds offsets from the spawn). With ``near`` (the model's structure with fewer proxy
    slots: :func:`near_model`), each control step fills the slots with the proxies nearest
    to the robot and steps that model; without it, the whole model."""

    def __init__(self, cfg: RobotConfig, model: mjx.Model, spawn_xy: jax.Array, near: mjx.Model | None = None):
        self.cfg, self.model, self.spawn_xy, self.near = cfg, model, spawn_xy, near

    def init(self, pose: jax.Array) -> mjx.Data:
        """MJX data with the robot at ``pose`` (3,), at rest. Derived fields (contacts,
        positions of bodies) stay empty: ``mjx.step`` recomputes all of them from qpos, qvel,
        ctrl and the warm start before it integrates, so a forward pass here would change no
        trajectory and only compile MJX's whole pipeline a second time (~5 s per reset)."""
        d = mjx.make_data(self.model if self.near is None else self.near)
        return d.replace(qpos=jnp.concatenate([pose[:2] - self.spawn_xy, pose[2:3]]))

    def pose(self, d: mjx.Data) -> jax.Array:
        """(3,) world x, y, yaw."""
        return jnp.concatenate([d.qpos[:2] + self.spawn_xy, d.qpos[2:3]])

    def nearby(self, pose: jax.Array) -> mjx.Model:
        """The model holding only the proxies nearest to ``pose`` (3,), ranked as MJX ranks
        pairs (centre distance less bounding radius; the sphere rides at the proxies' mid-
        height, so the distance is planar) and kept in their order in the model: MJX's own
        choice of the ``max_pairs`` nearest per substep, ties broken by order, is then the
        one it makes on the whole model while those lie among the slots."""
        if self.near is None:
            return self.model
        m, n = self.model, self.model.ngeom - 1
        dist = jnp.linalg.norm(m.geom_pos[:n, :2] - pose[:2], axis=-1) - m.geom_rbound[:n]
        keep = jnp.append(jnp.sort(jax.lax.top_k(-dist, self.near.ngeom - 1)[1]), n)
        return self.near.replace(body_pos=m.body_pos, body_quat=m.body_quat, qpos0=m.qpos0,  # the world's spawn
                                 **{f: getattr(m, f)[keep] for f in PROXY_FIELDS})

    def step(self, d: mjx.Data, cmd: jax.Array) -> mjx.Data:
        """Advance one control period under velocity command cmd = (v, w), clipped to limits."""
        v = jnp.clip(cmd[0], -self.cfg.max_speed, self.cfg.max_speed)
        w = jnp.clip(cmd[1], -self.cfg.max_turn_rate, self.cfg.max_turn_rate)
        model = self.nearby(self.pose(d))

        def sub(d, _):
            yaw = d.qpos[2]
            ctrl = jnp.stack([v * jnp.cos(yaw), v * jnp.sin(yaw), w])
            return _mjx_step(model, d.replace(ctrl=ctrl)), None

        d, _ = jax.lax.scan(sub, d, None, length=self.cfg.substeps)
        return d


def penetration(world: World, cfg: RobotConfig, pose: np.ndarray) -> np.ndarray:
    """How far (m) the robot's footprint disc at ``pose`` (..., 3) reaches into any box that
    reaches below the robot's height; 0 if clear. Ground truth for tests, independent of MJX."""
    s = world.scene
    xy = np.asarray(pose, float)[..., :2].reshape(-1, 2)
    local = s.to_local(np.concatenate([xy, np.zeros((len(xy), 1))], -1))[..., :2]
    dist = np.linalg.norm(np.maximum(np.abs(local) - s.half[None, :, :2], 0.0), axis=-1)
    low = (s.center[:, 2] - s.half[:, 2]) < cfg.height
    depth = np.where(low[None], cfg.radius - dist, 0.0).max(axis=1)
    return np.maximum(depth, 0.0).reshape(np.shape(pose)[:-1])
