"""Exact ray casting against yaw-rotated boxes and the floor plane, fused for the CPU.

The formulation measured fastest on a 2-core CPU (docs/performance.md): rays on the minor
(vectorised) axis; a running element-wise minimum over boxes; ``lax.scan`` over groups of
4 boxes with the 4 unrolled inside the body (:func:`unroll`); each box's cos/sin and the
ray origin in the box frame computed once per frame; the slab test per box; the
distance's float bits with the low bits replaced by the box index packed into one int32,
so the reduction over boxes is a single integer ``minimum``. The packing only decides
*which* box is hit; the distance to that box is then recomputed exactly, so distances are
exact, not quantised.

Shapes: B ray bundles (one per sensor per env), R rays per bundle, G boxes.
"""

from __future__ import annotations

import os
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.world.scene import FLOOR, NOTHING, Scene

CHUNK = 16  # scenes are padded to whole chunks of this many boxes


def unroll() -> int:
    """Boxes per step of a cast's scan, unrolled in its body: 4 by default, as fast to run
    as 16 and shorter to compile (docs/performance.md); the hits are bitwise the same for
    any grouping, as the minimum over packed keys is exact. ``$ROSMEERY_RAYCAST_UNROLL``
    sets another divisor of CHUNK."""
    value = os.environ.get("ROSMEERY_RAYCAST_UNROLL", "4")
    if not value.isdigit() or int(value) < 1 or CHUNK % int(value):
        raise InputError("$ROSMEERY_RAYCAST_UNROLL", "", f"{value!r} is not a divisor of {CHUNK}")
    return int(value)


_FAR = 1e6
INDEX_BITS = 12  # most box-index bits in the packed key: up to 4,095 boxes.
SMALL_BITS = 9  # the bits any scene of up to 511 boxes uses. Bucketed, not sized to the scene,
# so a world padded with extra boxes (a session's padding) breaks near-ties the same way as
# the world alone; and few, since the bits taken from the distance bound the error of a
# near-tie: 2^-(23 - bits) relative (6e-5 with 9 bits, 5e-4 with 12).


class RayScene(NamedTuple):
    """A :class:`Scene` on device, padded to a multiple of ``CHUNK`` boxes (jnp arrays).

    center (G, 3), half (G, 3), cos (G,), sin (G,), label (G,) int32 (object id or WALL),
    rgb (G, 3), floor_rgb (3,). Padding boxes sit far away and are never hit within range.
    """

    center: jax.Array
    half: jax.Array
    cos: jax.Array
    sin: jax.Array
    label: jax.Array
    rgb: jax.Array
    floor_rgb: jax.Array

    @property
    def num_boxes(self) -> int:
        return int(self.center.shape[0])


class Hit(NamedTuple):
    """Per ray: dist (..., R) along the ray (``max_range`` when nothing is hit), box (..., R)
    int32 index or -1, label (..., R) int32 (object id, WALL, FLOOR or NOTHING), normal
    (..., R, 3) unit surface normal at the hit (zero for none)."""

    dist: jax.Array
    box: jax.Array
    label: jax.Array
    normal: jax.Array


def padded_boxes(num_boxes: int) -> int:
    """The boxes of a scene of ``num_boxes`` once padded to whole chunks (its RayScene's G)."""
    return -(-num_boxes // CHUNK) * CHUNK


def ray_scene(scene: Scene, boxes: int | None = None) -> RayScene:
    """Upload a world's scene, padded to ``boxes`` (at least its own) in whole chunks."""
    g = scene.num_boxes
    pad = padded_boxes(max(g, boxes or 0)) - g
    center = np.concatenate([scene.center, np.full((pad, 3), _FAR, np.float32)])
    half = np.concatenate([scene.half, np.full((pad, 3), 0.01, np.float32)])
    yaw = np.concatenate([scene.yaw, np.zeros(pad, np.float32)])
    label = np.concatenate([scene.object_id, np.full(pad, NOTHING, np.int32)])
    rgb = np.concatenate([scene.rgb, np.zeros((pad, 3), np.float32)])
    f = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return RayScene(f(center), f(half), f(np.cos(yaw)), f(np.sin(yaw)), jnp.asarray(label, jnp.int32),
                    f(rgb), f(scene.floor_rgb))


def crosses_plane(scene: Scene, height: float) -> np.ndarray:
    """(G,) bool: the boxes a horizontal ray at ``height`` can hit (boxes rotate only about z),
    with a millimetre to spare: a box left out could not be hit, and one kept that is never
    hit changes nothing, since the cast keeps the boxes' order."""
    return np.abs(scene.center[:, 2] - np.float32(height)) <= scene.half[:, 2] + 1e-3


def index_bits(num_boxes: int) -> int:
    """Bits that index ``num_boxes`` boxes in the packed key."""
    bits = max(1, int(np.ceil(np.log2(num_boxes + 1))))
    if bits > INDEX_BITS:
        raise ValueError(f"{num_boxes} boxes: the packed kernel handles at most {2 ** INDEX_BITS - 1}")
    return bits


def scene_bits(num_boxes: int) -> int:
    """The packed key's index bits for a scene of ``num_boxes``: SMALL_BITS up to 511, else INDEX_BITS."""
    index_bits(num_boxes)  # raises beyond INDEX_BITS
    return SMALL_BITS if num_boxes < 2 ** SMALL_BITS else INDEX_BITS


def _box_groups(rs: RayScene, per_step: int):
    """Scan inputs over groups of ``per_step`` boxes: (first index, centers, halves, cos, sin)."""
    n = rs.num_boxes // per_step
    return (jnp.arange(n, dtype=jnp.int32) * per_step, rs.center.reshape(n, per_step, 3),
            rs.half.reshape(n, per_step, 3), rs.cos.reshape(n, per_step), rs.sin.reshape(n, per_step))


def _pack(t, keep, index):
    """Distance bits (non-negative float, so ordered like ints) with the box index in the low bits."""
    return (jax.lax.bitcast_convert_type(jnp.minimum(t, jnp.float32(3e38)), jnp.int32) & keep) | index


def _slab(lx, ly, lz, dx, dy, dz, hx, hy, hz):
    """Entry distance of rays (origin l*, direction d*, box frame) into a centred box; inf if missed.

    Rays starting inside a box do not hit it (the robot never stands inside a solid).
    """
    big = jnp.float32(1e30)
    ix = 1.0 / jnp.where(jnp.abs(dx) < 1e-12, 1e-12, dx)
    iy = 1.0 / jnp.where(jnp.abs(dy) < 1e-12, 1e-12, dy)
    iz = 1.0 / jnp.where(jnp.abs(dz) < 1e-12, 1e-12, dz)
    tx1, tx2 = (-hx - lx) * ix, (hx - lx) * ix
    ty1, ty2 = (-hy - ly) * iy, (hy - ly) * iy
    tz1, tz2 = (-hz - lz) * iz, (hz - lz) * iz
    tmin = jnp.maximum(jnp.maximum(jnp.minimum(tx1, tx2), jnp.minimum(ty1, ty2)), jnp.minimum(tz1, tz2))
    tmax = jnp.minimum(jnp.minimum(jnp.maximum(tx1, tx2), jnp.maximum(ty1, ty2)), jnp.maximum(tz1, tz2))
    return jnp.where((tmax >= tmin) & (tmin > 0.0), tmin, big)


def cast(rs: RayScene, origin: jax.Array, dirs: jax.Array, max_range: float, bits: int | None = None,
         boxes_per_step: int | None = None) -> Hit:
    """Cast bundles of rays. origin (..., 3) one per bundle; dirs (..., R, 3) unit vectors;
    ``bits`` of the packed key index the boxes (default :func:`scene_bits`); ``boxes_per_step``
    of the scan (default :func:`unroll`) change nothing but compile and run times."""
    per_step = boxes_per_step or unroll()
    lead = origin.shape[:-1]
    o = origin.reshape(-1, 3)
    d = dirs.reshape(o.shape[0], -1, 3)
    bits = bits or scene_bits(rs.num_boxes)
    keep = jnp.int32(~((1 << bits) - 1))
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]  # (B, R)
    inf_bits = jax.lax.bitcast_convert_type(jnp.float32(jnp.inf), jnp.int32)

    def group(best, xs):
        base, c, h, cs, sn = xs
        for k in range(per_step):
            ox, oy, oz = o[:, 0] - c[k, 0], o[:, 1] - c[k, 1], o[:, 2] - c[k, 2]  # (B,)
            lx = (cs[k] * ox + sn[k] * oy)[:, None]
            ly = (-sn[k] * ox + cs[k] * oy)[:, None]
            ldx = cs[k] * dx + sn[k] * dy
            ldy = -sn[k] * dx + cs[k] * dy
            t = _slab(lx, ly, oz[:, None], ldx, ldy, dz, h[k, 0], h[k, 1], h[k, 2])
            best = jnp.minimum(best, _pack(t, keep, base + k))
        return best, None

    best, _ = jax.lax.scan(group, jnp.full(dx.shape, inf_bits, jnp.int32), _box_groups(rs, per_step))
    box = best & ~keep  # (B, R)
    out = _resolve(rs, o, d, box, max_range)
    r = d.shape[1]
    return Hit(*(a.reshape(*lead, r, *a.shape[2:]) for a in out))


def materialized(x: jax.Array) -> jax.Array:
    """``x`` (float), computed once into memory before its consumers read it.

    XLA fuses cheap elementwise producers into their consumers, gathers included, and repeats
    the producer in each consumer that fuses it. A reduction is never fused into a consumer,
    so a max against the lowest finite float (which changes no value but -inf) ends the
    fusion here; ``lax.optimization_barrier`` does not, as XLA's CPU pipeline removes it
    first. Used where the repeat is costly: the depth image, read once per ground-truth
    sample by the coverage test (35,000 samples against 3,072 pixels in the Large Office:
    coverage cost 14 ms per B=64 step fused against 4 ms alone), and the winning box's
    slab test in :func:`_resolve`, read by the distance, label and normal."""
    lowest = jnp.full_like(x, jnp.finfo(x.dtype).min)
    return jnp.max(jnp.stack([x, lowest], -1), -1)


def _resolve(rs: RayScene, o: jax.Array, d: jax.Array, box: jax.Array, max_range: float) -> Hit:
    """Exact distance, label and normal of rays o (B, 3) + t d (B, R, 3) against the chosen
    box (B, R) or the floor, whichever is nearer."""
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]

    # Exact distance and normal for the winning box.
    c, h = rs.center[box], rs.half[box]
    cs, sn = rs.cos[box], rs.sin[box]
    ox, oy, oz = o[:, None, 0] - c[..., 0], o[:, None, 1] - c[..., 1], o[:, None, 2] - c[..., 2]
    lx, ly = cs * ox + sn * oy, -sn * ox + cs * oy
    ldx, ldy = cs * dx + sn * dy, -sn * dx + cs * dy
    # Materialized: the label, distance and normal consumers would each repeat the gathers
    # and the slab test (RGB frames 13-17 % slower).
    t_box = materialized(_slab(lx, ly, oz, ldx, ldy, dz, h[..., 0], h[..., 1], h[..., 2]))
    t_floor = jnp.where(dz < 0, -o[:, None, 2] / jnp.where(dz < 0, dz, -1.0), jnp.inf)
    floor_first = t_floor < t_box
    t = jnp.minimum(t_box, t_floor)
    hit = t <= max_range
    # Box normal: the face whose slab the hit point is on (largest |p| / half ratio; x before
    # y before z on a tie), as selects rather than an argmax and a one-hot.
    px, py, pz = (lx + t_box * ldx) / h[..., 0], (ly + t_box * ldy) / h[..., 1], (oz + t_box * dz) / h[..., 2]
    ax, ay, az = jnp.abs(px), jnp.abs(py), jnp.abs(pz)
    on_x = (ax >= ay) & (ax >= az)
    on_y = ~on_x & (ay >= az)
    sx, sy = jnp.where(on_x, jnp.sign(px), 0.0), jnp.where(on_y, jnp.sign(py), 0.0)
    sz = jnp.where(on_x | on_y, 0.0, jnp.sign(pz))
    n_box = jnp.stack([cs * sx - sn * sy, sn * sx + cs * sy, sz], -1)
    normal = jnp.where(floor_first[..., None], jnp.array([0.0, 0.0, 1.0]), n_box)
    label = jnp.where(floor_first, FLOOR, rs.label[box])
    box = jnp.where(floor_first, -1, box)
    return Hit(
        jnp.where(hit, t, max_range),
        jnp.where(hit, box, -1),
        jnp.where(hit, label, NOTHING),
        jnp.where(hit[..., None], normal, 0.0),
    )


def cast_columns(rs: RayScene, origin: jax.Array, dirs: jax.Array, max_range: float,
                 bits: int | None = None, boxes_per_step: int | None = None) -> Hit:
    """Cast a level camera's rays (H, W, 3): every column shares one horizontal direction.

    Exact, like :func:`cast`, and about twice as fast for camera images: the x / y slab test
    runs once per column and box, and each pixel adds only the z slab. Along a column,
    parameterise each ray by its horizontal distance s; a box's x / y slabs give an interval
    [s0, s1] for the column, its z slab an interval per pixel, and the pixel's nearest box is
    the one with the smallest entry s (t = s / |horizontal part of d|, the same order).
    origin (..., 3); dirs (..., H, W, 3) with each column's horizontal direction constant;
    ``boxes_per_step`` as in :func:`cast`.
    """
    per_step = boxes_per_step or unroll()
    lead = origin.shape[:-1]
    h_, w_ = dirs.shape[-3], dirs.shape[-2]
    o = origin.reshape(-1, 3)
    d = dirs.reshape(o.shape[0], h_, w_, 3)
    dc = jnp.swapaxes(d, 1, 2)  # (B, W, H, 3): a column's pixels on the minor axis
    horiz = jnp.linalg.norm(dc[..., :2], axis=-1)  # (B, W, H)
    ex = dc[:, :, 0, 0] / horiz[:, :, 0]  # (B, W) unit horizontal direction per column
    ey = dc[:, :, 0, 1] / horiz[:, :, 0]
    slope = dc[..., 2] / horiz  # dz per metre of horizontal travel
    islope = 1.0 / jnp.where(jnp.abs(slope) < 1e-12, 1e-12, slope)  # (B, H, W)
    bits = bits or scene_bits(rs.num_boxes)
    keep = jnp.int32(~((1 << bits) - 1))
    inf_bits = jax.lax.bitcast_convert_type(jnp.float32(jnp.inf), jnp.int32)
    big = jnp.float32(1e30)
    iex_ = lambda a: 1.0 / jnp.where(jnp.abs(a) < 1e-12, 1e-12, a)  # noqa: E731

    def group(best, xs):
        base, c, h, cs, sn = xs
        for k in range(per_step):
            ox, oy = o[:, 0] - c[k, 0], o[:, 1] - c[k, 1]  # (B,)
            lx = (cs[k] * ox + sn[k] * oy)[:, None]
            ly = (-sn[k] * ox + cs[k] * oy)[:, None]
            ix = iex_(cs[k] * ex + sn[k] * ey)  # (B, W)
            iy = iex_(-sn[k] * ex + cs[k] * ey)
            tx1, tx2 = (-h[k, 0] - lx) * ix, (h[k, 0] - lx) * ix
            ty1, ty2 = (-h[k, 1] - ly) * iy, (h[k, 1] - ly) * iy
            s0 = jnp.maximum(jnp.minimum(tx1, tx2), jnp.minimum(ty1, ty2))[:, :, None]  # (B, W, 1)
            s1 = jnp.minimum(jnp.maximum(tx1, tx2), jnp.maximum(ty1, ty2))[:, :, None]
            zlo = (c[k, 2] - h[k, 2] - o[:, 2])[:, None, None]
            zhi = (c[k, 2] + h[k, 2] - o[:, 2])[:, None, None]
            z1, z2 = zlo * islope, zhi * islope  # (B, W, H)
            enter = jnp.maximum(s0, jnp.minimum(z1, z2))
            leave = jnp.minimum(s1, jnp.maximum(z1, z2))
            t = jnp.where((leave >= enter) & (enter > 0.0), enter, big)
            best = jnp.minimum(best, _pack(t, keep, base + k))
        return best, None

    best, _ = jax.lax.scan(group, jnp.full(islope.shape, inf_bits, jnp.int32), _box_groups(rs, per_step))
    box = jnp.swapaxes(best & ~keep, 1, 2).reshape(o.shape[0], h_ * w_)
    out = _resolve(rs, o, d.reshape(o.shape[0], h_ * w_, 3), box, max_range)
    return Hit(*(a.reshape(*lead, h_ * w_, *a.shape[2:]) for a in out))
