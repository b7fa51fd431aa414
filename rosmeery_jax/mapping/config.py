"""The perceived mapper's settings, each rule's (:mod:`rosmeery_jax.mapping.perceived`;
specified in docs/mapping.md; what each buys, measured: experiments/mapping)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PerceivedConfig:
    voxel: float = 0.025  # m: half the surface samples' spacing (rule 3)
    floor_z: float = 0.03  # m: points lower than this are floor
    edge_abs: float = 0.03  # m: neighbouring pixels further apart in depth than edge_abs +
    edge_rel: float = 0.03  # edge_rel * depth lie on different surfaces (rule 2)
    min_share: float = 0.2  # the nearest segment with this share of a box's pixels is the object,
    inside: float = 0.5  # of the segments with at least this share of their pixels in the box
    front_share: float = 0.05  # a segment with this share of the box, standing more than
    behind: float = 0.5  # m nearer than the object's, shows the latter to be background (inf: off)
    part_share: float = 0.02  # rule 2: segments with this share of a box's pixels standing at most
    part_behind: float = 0.3  # m behind the object's nearest point are its parts (part_share inf: none)
    cell: float = 0.05  # m: the association's coarse cells (rule 4)
    overlap: float = 0.2  # share of a detection's cells an instance must hold to take it,
    same_overlap: float = 0.05  # or, if it carries the detection's label, this share (rule 4)
    min_voxels: int = 3  # detections with fewer voxels are dropped (a few stray pixels)
    min_views: int = 2  # detections that confirm an instance (rule 6),
    min_conf: float = 0.6  # one of them at least this confident (rule 6; 0: any the session passes),
    alone_conf: float = 0.7  # or one detection this confident (rule 6; inf: never one alone)
    grow: float = 0.5  # share of a frame segment's cells an instance must hold to grow into it (rule 7; 0: off),
    grow_margin: float = 0.3  # m: within its detections' points' 3D box widened by this (rule 7; inf: anywhere)
    depth_every: int = 1  # rule 8: rule 7 on every n-th step's depth camera between detector frames (0: off)
    absorb: float = 0.8  # rule 9: share of an instance's points over a larger one's plan-view box that
    absorb_margin: float = 0.1  # makes it part of that one (inf: off); m: the box widened by this;
    absorb_size: float = 0.5  # the smaller holds fewer points than this share of the larger's
    bare: tuple[str, ...] = ("chair", "couch", "bench")  # rule 9: nothing is set on these, so an instance
    placed: tuple[str, ...] = ("monitor", "tv", "laptop", "book", "vase")  # of these over one of them is its part
    wall_above: float = 2.2  # m: rule 10: a point higher than this is a wall's (inf: off);
    wall_cell: float = 0.1  # m: the plan-view cells of the walls
