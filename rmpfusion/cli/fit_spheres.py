"""``rmpfusion-fit-spheres``: control spheres fitted to a URDF's collision geometry, written as a robot description.

    rmpfusion-fit-spheres URDF --joints J1 J2 ... --ee-link LINK [--ee-offset X Y Z] [--spheres K] [--links L ...]
                          --name NAME --out conf/robot/NAME.yaml [--figure coverage.png]
    rmpfusion-fit-spheres --check conf/robot/NAME.yaml [--figure coverage.png]

The first form fits K spheres per link (every link an actuated joint moves that has collision geometry, or
``--links``), prints per link and in all the coverage (the fraction of an independent sample of surface points
inside some sphere of their link; the target is ≥ 99 %) and the overshoot (how far a sphere's surface reaches from
the link's surface), writes the robot YAML (never over an existing file unless ``--force``) and the coverage
figure. The second measures the spheres an existing robot YAML already has.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import yaml

from ..files import atomic_write_bytes
from ..maps.urdf import parse_urdf
from ..plots.spheres import plot_coverage
from ..robots import RobotDescription, build_robot
from ..robots.geometry import collision_meshes
from ..robots.spheres import LinkFit, fit_link, measure, summary

TARGET = 0.99


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rmpfusion-fit-spheres", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("urdf", nargs="?", help="a URDF path, or pkg://<package>/<path> inside an installed package")
    ap.add_argument("--check", metavar="ROBOT_YAML", help="measure the spheres of an existing robot description")
    ap.add_argument("--joints", nargs="+", help="the actuated joints, in configuration order")
    ap.add_argument("--ee-link", help="the end effector's link")
    ap.add_argument("--ee-offset", nargs=3, type=float, default=[0.0, 0.0, 0.0], metavar=("X", "Y", "Z"))
    ap.add_argument("--name", help="the robot's name (figures, messages)")
    ap.add_argument("--spheres", type=int, default=2, help="spheres per link (default 2)")
    ap.add_argument("--links", nargs="+", help="links to cover (default: every moved link with collision geometry)")
    ap.add_argument("--margin", type=float, default=0.002, help="added to every radius (m, default 0.002)")
    ap.add_argument("--home", nargs="+", type=float, help="home configuration (default: 0, or the middle of a "
                                                          "joint's range when 0 is outside it)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="the robot YAML to write")
    ap.add_argument("--force", action="store_true", help="replace --out if it exists")
    ap.add_argument("--figure", help="the coverage figure (PNG) to write")
    return ap


def _home(urdf: str, joints: list[str], given: list[float] | None) -> list[float]:
    if given is not None:
        return given
    model = parse_urdf(urdf)
    out = []
    for j in joints:
        lo, hi = model.joint(j).lower, model.joint(j).upper
        out.append(0.0 if lo <= 0.0 <= hi else (lo + hi) / 2 if math.isfinite(lo + hi) else 0.0)
    return out


def _fit(args) -> tuple[dict, list[LinkFit]]:
    meshes = collision_meshes(args.urdf)
    # a first description without spheres: checks the joints and links against the URDF, says which links move
    base = RobotDescription(name=args.name, urdf=args.urdf, joints=args.joints,
                            end_effector={"link": args.ee_link, "offset": args.ee_offset},
                            home=_home(args.urdf, args.joints, args.home))
    robot = build_robot(base)
    links = args.links or [link for link in parse_urdf(args.urdf).link_names() if link in meshes and robot.moves(link)]
    missing = [link for link in links if link not in meshes]
    if missing:
        raise ValueError(f"--links {missing} have no collision geometry; links with some: {', '.join(meshes)}")
    fits = [fit_link(link, meshes[link], args.spheres, args.margin, seed=args.seed) for link in links]
    spheres = [{"link": f.link, "offset": [round(float(v), 4) for v in c], "radius": round(float(r) + 5e-5, 4)}
               for f in fits for c, r in zip(f.centers, f.radii)]
    return {**base.model_dump(mode="json", exclude={"control_points"}), "control_points": spheres}, fits


def _check(path: str) -> tuple[dict, list[LinkFit]]:
    data = yaml.safe_load(Path(path).read_text())
    desc = RobotDescription.model_validate(data)
    meshes = collision_meshes(desc.urdf)
    by_link: dict[str, list] = {}
    for cp in desc.control_points:
        by_link.setdefault(cp.link, []).append(cp)
    fits = [measure(link, meshes[link], [c.offset for c in cps], [c.radius for c in cps])
            for link, cps in by_link.items() if link in meshes]
    return data, fits


def _report(fits: list[LinkFit]) -> str:
    lines = [f"  {f.link}: {len(f.radii)} spheres, coverage {100 * f.coverage:.2f} %, overshoot max "
             f"{1000 * f.overshoot.max():.1f} mm" for f in fits]
    s = summary(fits)
    verdict = "meets" if s["coverage"] >= TARGET else "misses"
    lines.append(f"all: {s['spheres']} spheres, coverage {100 * s['coverage']:.2f} % ({verdict} the "
                 f"{100 * TARGET:.0f} % target), overshoot mean {1000 * s['overshoot_mean']:.1f} mm, max "
                 f"{1000 * s['overshoot_max']:.1f} mm")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.check:
            _, fits = _check(args.check)
        else:
            if not (args.urdf and args.joints and args.ee_link and args.name and args.out):
                _parser().error("fitting needs URDF, --joints, --ee-link, --name and --out (or --check ROBOT_YAML)")
            if Path(args.out).exists() and not args.force:
                raise FileExistsError(f"{args.out} exists; choose another --out or add --force to replace it")
            description, fits = _fit(args)
            header = (f"# @package env.robot\n# {args.name}: written by rmpfusion-fit-spheres ({args.spheres} spheres "
                      f"per link, margin {args.margin} m); edit home, limits and the spheres as needed.\n")
            atomic_write_bytes(args.out, (header + yaml.safe_dump(description, sort_keys=False)).encode())
    except (ValueError, FileNotFoundError, FileExistsError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(_report(fits))
    if args.figure:
        print(f"figure: {plot_coverage(args.figure, fits)}")
    if not args.check:
        print(f"robot description: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
