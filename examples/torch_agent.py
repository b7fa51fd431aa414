"""A PyTorch agent through Gymnasium: it finds frontier cells (free, next to unknown) on each
robot's own occupancy map with a torch convolution and sends the robot to the nearest one
at least 1 m away, avoiding targets its navigator gave up on. Any Python agent plugs in the
same way.

    python examples/torch_agent.py --world small_office --duration 60          # its own loop
    rosmeery run --worlds small_office --detector off \
        --policies frontier,agent:examples/torch_agent.py:TorchFrontier       # in a session
"""

import argparse

import numpy as np
import torch

from rosmeery_jax.gym import Agent, GymConfig, VectorEnv

GAVE_UP = (3, 4, 5)  # navigator status: stuck, unreachable, timed out


class TorchFrontier(Agent):
    name = "torch_frontier"

    def __init__(self, env):
        super().__init__(env)
        grid = env.bank.env.grid
        self.origin, self.resolution = np.asarray(grid.origin), grid.resolution
        self.near = torch.nn.Conv2d(1, 1, 3, padding=1, bias=False)  # counts unknown neighbours
        self.near.weight.data.fill_(1.0)
        self.last = [None] * env.num_envs  # each robot's last target
        self.failed = [[] for _ in range(env.num_envs)]  # targets its navigator gave up on

    @torch.no_grad()
    def act(self, obs):
        grids = torch.as_tensor(obs["occupancy"], dtype=torch.float32)[:, None]  # (B, 1, H, W)
        frontier = (grids == 0) & (self.near((grids == -1).float()) > 0)
        for i, status in enumerate(obs["nav_status"][:, 0]):
            if status in GAVE_UP and self.last[i] is not None:
                self.failed[i].append(self.last[i][:2])
        self.last = [self._target(f[0], pose, self.failed[i]) for i, (f, pose) in enumerate(zip(frontier, obs["pose"]))]
        return np.stack(self.last)

    def _target(self, frontier, pose, failed):
        rows, cols = torch.nonzero(frontier, as_tuple=True)
        x, y, yaw = (float(v) for v in pose)
        if len(rows) == 0:
            return np.float32([x, y, yaw])  # nothing left to explore: stay
        cx = self.origin[0] + (cols.numpy() + 0.5) * self.resolution
        cy = self.origin[1] + (rows.numpy() + 0.5) * self.resolution
        dist = np.hypot(cx - x, cy - y)
        for fx, fy in failed:  # not near a target given up on
            dist[np.hypot(cx - fx, cy - fy) < 0.5] = np.inf
        far = np.flatnonzero((dist >= 1.0) & np.isfinite(dist))
        if not len(far) and not np.isfinite(dist).any():
            return np.float32([x, y, yaw + np.pi / 2])  # every frontier failed: turn and look
        k = far[np.argmin(dist[far])] if len(far) else int(np.argmax(np.where(np.isfinite(dist), dist, -1)))
        return np.float32([cx[k], cy[k], np.arctan2(cy[k] - y, cx[k] - x)])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--world", default="small_office")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--robots", type=int, default=2)
    args = ap.parse_args()
    env = VectorEnv([args.world], args.robots, GymConfig(duration=args.duration))
    agent = TorchFrontier(env)
    obs, _ = env.reset(seed=0)
    gained, done = np.zeros(args.robots), False
    while not done:
        obs, reward, terminated, truncated, _ = env.step(agent.act(obs))
        gained += reward  # the reward is the increase of ORI: its sum is what the run added
        done = bool(truncated.all() or terminated.all())
    print(f"{args.world}: ORI gained per robot {np.round(gained, 3)} in {args.duration:g} s")


if __name__ == "__main__":
    main()
