"""The ``rosmeery worlds`` and ``rosmeery world`` sub-commands: list, generate, measure and
draw worlds."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from rosmeery_jax.apps.columns import columns
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import output_folder, require_new
from rosmeery_jax.core.specs import MAX_WORLDS
from rosmeery_jax.world import load_world, world_names
from rosmeery_jax.world.census import stats_table, summary, world_names_in
from rosmeery_jax.world.draw import picture_format, save_world_picture
from rosmeery_jax.world.generate import GenOptions, check_options, generate
from rosmeery_jax.world.procedural import check_unchanged, write_world


def add_worlds(sub) -> None:
    """The ``worlds`` command and its ``generate`` and ``stats``."""
    p = sub.add_parser("worlds", help="list the built-in worlds with object and sample counts")
    p.add_argument("--json", action="store_true", help="print one JSON list instead of a table")
    p.add_argument("--pictures", metavar="DIR", help="also draw every world's top-down map into DIR")
    p.set_defaults(func=_cmd_worlds)
    wsub = p.add_subparsers(dest="worlds_command", metavar="{generate,stats}")
    s = wsub.add_parser("generate", help="write procedural worlds (MJCF, the format of the built-in ones)")
    s.add_argument("--kind", required=True, help="apartment, office, kitchen or lab")
    s.add_argument("--seed", type=int, required=True, metavar="S", help="the first seed")
    s.add_argument("--count", type=int, default=1, metavar="N", help="worlds of seeds S..S+N-1 (default 1)")
    s.add_argument("--rooms", type=int, metavar="R", help="rooms (default: by kind)")
    s.add_argument("--objects", type=int, metavar="K", help="objects (default: by kind)")
    s.add_argument("--clutter", type=float, default=0.2, metavar="X", help="share of small clutter objects (0.2)")
    s.add_argument("--tuck", type=float, default=0.0, metavar="X",
                   help="share of chairs pushed in under their desk or table (0)")
    s.add_argument("--turn", type=float, default=0.0, metavar="DEG",
                   help="chairs at desks and tables turned by up to DEG degrees either way (0)")
    s.add_argument("--islands", type=float, default=0.0, metavar="X",
                   help="share of desk groups set as free-standing rows of desks (0)")
    s.add_argument("--spare", type=float, default=0.0, metavar="X",
                   help="share of clutter objects that are a spare chair against a wall (0)")
    s.add_argument("--out", required=True, metavar="DIR")
    s.add_argument("--check", action="store_true", help="also load every world with the loader's validation")
    s.set_defaults(func=_cmd_worlds_generate)
    s = wsub.add_parser("stats", help="objects, floor and reachable area, categories and samples of worlds")
    s.add_argument("worlds", nargs="+", metavar="DIR_OR_NAMES", help="folders of world files, names, paths "
                   "or procedural:KIND:A-B")
    s.add_argument("--rows", type=int, default=40, metavar="N", help="print per-world rows up to N worlds (40)")
    s.add_argument("--csv", action="store_true", help="print the per-world table as CSV")
    s.set_defaults(func=_cmd_worlds_stats)


def add_world(sub) -> None:
    """The ``world`` command: ``show``."""
    p = sub.add_parser("world", help="commands on one world")
    wsub = p.add_subparsers(dest="world_command", required=True)
    s = wsub.add_parser("show", help="draw a world's top-down map with labelled objects")
    s.add_argument("world", metavar="NAME_OR_PATH", help="built-in world name or path to an MJCF file")
    s.add_argument("--out", required=True, metavar="FILE.png")
    s.set_defaults(func=_cmd_world_show)



def _cmd_worlds(args) -> int:
    if args.pictures and Path(args.pictures).exists() and not Path(args.pictures).is_dir():
        raise InputError(args.pictures, "--pictures", "is a file, not a folder")
    worlds = [load_world(n) for n in world_names()]
    summaries = [w.summary() for w in worlds]
    for w in worlds if args.pictures else ():  # every picture checked before any is written
        require_new(Path(args.pictures) / f"{w.name}.png", "--pictures", kind="file")
    if args.pictures:
        for w, s in zip(worlds, summaries):
            s["picture"] = str(save_world_picture(w, Path(args.pictures) / f"{w.name}.png"))
    if args.json:
        print(json.dumps(summaries, indent=2))
        return 0
    rows = [(s["name"], s["title"], str(s["objects"]), str(s["samples"]), str(s["boxes"]),
             f"{s['reachable_area_m2']:.1f}", ", ".join(f"{c} x{k}" for c, k in s["categories"].items()))
            for s in summaries]
    print(columns(("world", "title", "objects", "samples", "boxes", "reach m2", "categories"), rows,
                  right=(2, 3, 4, 5)))
    for s in summaries:
        if "picture" in s:
            print(f"wrote {s['picture']}")
    return 0


def _gen_options(args, seed: int) -> GenOptions:
    return GenOptions(args.kind, seed, args.rooms, args.objects, args.clutter, args.tuck, args.turn, args.islands,
                      args.spare)


def _cmd_worlds_generate(args) -> int:
    if args.count < 1:
        raise InputError("command line", "--count", f"{args.count}: at least 1")
    check_options(_gen_options(args, args.seed), "command line")
    if args.count > MAX_WORLDS:
        raise InputError("command line", "--count", f"{args.count}: at most {MAX_WORLDS:,} worlds at once")
    out = Path(args.out)
    if out.is_symlink() and not out.exists():
        raise InputError(str(out), "--out", "is a broken or looping symbolic link")
    if out.exists() and not out.is_dir():
        raise InputError(str(out), "--out", "exists and is not a folder")
    t0 = time.perf_counter()
    layouts = [generate(_gen_options(args, s))
               for s in range(args.seed, args.seed + args.count)]  # all or nothing: generate, then write
    gen_s = time.perf_counter() - t0
    for layout in layouts:  # an edited world in --out refuses the whole command, before any write
        check_unchanged(out / f"{layout.options.name}.xml", layout.xml())
    with output_folder(out):
        paths = [write_world(layout, out) for layout in layouts]
    total_s = time.perf_counter() - t0
    print(f"wrote {len(paths)} {args.kind} worlds to {out}/ in {total_s:.2f} s "
          f"({1000 * gen_s / len(paths):.1f} ms per world to generate, the rest writing)")
    if args.check:
        t1 = time.perf_counter()
        for p in paths:
            load_world(p)  # a world that fails the loader's validation stops here, in one line
        print(f"all {len(paths)} pass the loader's validation ({time.perf_counter() - t1:.1f} s)")
    return 0


def _cmd_worlds_stats(args) -> int:
    if args.rows < 0:
        raise InputError("command line", "--rows", f"{args.rows} must be a whole number >= 0 (0: the summary only)")
    names = world_names_in(args.worlds)
    table, cats = stats_table(names)
    if args.csv:
        table.to_csv(sys.stdout, index=False)
        return 0
    if len(table) <= args.rows:
        print(table.to_string(index=False))
    if len(table) > 1:
        print(f"\n{len(table)} worlds:")
        print(summary(table).to_string())
    print("\ncategories (objects over all worlds): " + ", ".join(f"{c} {n}" for c, n in cats.items()))
    return 0


def _cmd_world_show(args) -> int:
    if Path(args.out).is_dir():
        raise InputError(args.out, "--out", "is a folder: name the picture to write (FILE.png)")
    require_new(args.out, kind="file")  # a picture already there is never replaced
    picture_format(args.out)
    world = load_world(args.world)
    out = save_world_picture(world, args.out)
    print(f"wrote {out} ({world.title}: {world.truth.num_objects} objects)")
    return 0
