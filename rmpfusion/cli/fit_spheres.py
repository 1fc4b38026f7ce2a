"""``rmpfusion-fit-spheres``: control spheres fitted to a URDF's collision geometry, written as a robot description.

    rmpfusion-fit-spheres URDF --joints J1 J2 ... --ee-link LINK [--ee-offset X Y Z] [--spheres K] [--links L ...]
                          [--package-dir NAME=PATH ...] [--home Q1 Q2 ...] --name NAME --out conf/robot/NAME.yaml
                          [--figure coverage.png]
    rmpfusion-fit-spheres --check conf/robot/NAME.yaml [--figure coverage.png]

The first form fits K spheres per link (every link an actuated joint moves that has collision geometry, or visual
geometry when it has no collision geometry, or ``--links``), prints per link and in all the coverage (the fraction
of an independent sample of surface points inside some sphere of their link; the target is ≥ 99 %) and the
overshoot (how far a sphere's surface reaches from the link's surface), writes the robot YAML (never over an
existing file unless ``--force``) and the coverage figure. Only the meshes of the fitted links are read;
``package://`` meshes are found as ``rmpfusion/robots/packages.py`` says (``--package-dir`` first). Without
``--home`` a home is proposed: the middle of every joint's range, or the configuration nearest to it whose spheres
clear the ground. The second form measures the spheres an existing robot YAML already has.
"""

from __future__ import annotations

import argparse
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from ..files import atomic_write_bytes
from ..maps.urdf import parse_urdf
from ..plots.spheres import plot_coverage
from ..robots import RobotDescription, build_robot
from ..robots.geometry import collision_meshes, link_geometry, links_with_geometry
from ..robots.home import mid_range, propose_home
from ..robots.packages import package_names
from ..robots.spheres import LinkFit, fit_link, measure, summary
from ._common import one_line

TARGET = 0.99


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="rmpfusion-fit-spheres", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("urdf", nargs="?", help="a URDF path, or pkg://<package>/<path> inside an installed package")
    ap.add_argument("--check", metavar="ROBOT_YAML", help="measure the spheres of an existing robot description")
    ap.add_argument("--joints", nargs="+", help="the actuated joints, in configuration order")
    ap.add_argument("--ee-link", help="the end effector's link")
    ap.add_argument("--ee-offset", nargs=3, type=float, default=[0.0, 0.0, 0.0], metavar=("X", "Y", "Z"))
    ap.add_argument("--name", help="the robot's name (figures, messages)")
    ap.add_argument("--spheres", type=int, default=2, help="spheres per link (default 2)")
    ap.add_argument("--links", nargs="+", help="links to cover (default: every moved link with collision geometry)")
    ap.add_argument("--margin", type=float, default=0.002, help="added to every radius (m, default 0.002)")
    ap.add_argument(
        "--home",
        nargs="+",
        type=float,
        help="home configuration (default: proposed, the middle of every joint's range clear of the ground)",
    )
    ap.add_argument(
        "--package-dir",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="the folder of ROS package NAME, for package://NAME/ meshes (repeatable; searched first)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", help="the robot YAML to write")
    ap.add_argument("--force", action="store_true", help="replace --out if it exists")
    ap.add_argument("--figure", help="the coverage figure (PNG) to write")
    return ap


def _packages(given: list[str]) -> dict[str, str]:
    out = {}
    for item in given:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise ValueError(f"--package-dir {item!r}: write NAME=PATH (the ROS package's name and its folder)")
        out[name] = os.path.abspath(path) if "://" not in path else path
    return out


def _fit(args) -> tuple[dict, list[LinkFit], list[str]]:
    packages = _packages(args.package_dir)
    # a first description without spheres: checks the joints and links against the URDF, says which links move
    base = RobotDescription(
        name=args.name,
        urdf=args.urdf,
        packages=packages,
        joints=args.joints,
        end_effector={"link": args.ee_link, "offset": args.ee_offset},
        home=args.home if args.home is not None else _draft_home(args, packages),
    )
    robot = build_robot(base)
    available = links_with_geometry(args.urdf)
    links = args.links or [
        link for link in parse_urdf(args.urdf).link_names() if link in available and robot.moves(link)
    ]
    missing = [link for link in links if link not in available]
    if missing:
        raise ValueError(
            f"--links {missing} have no collision or visual geometry; links with some: {', '.join(available)}"
        )
    geometry = link_geometry(args.urdf, links, packages)
    fits = [fit_link(link, geometry.meshes[link], args.spheres, args.margin, seed=args.seed) for link in links]
    spheres = [
        {"link": f.link, "offset": [round(float(v), 4) for v in c], "radius": round(float(r) + 5e-5, 4)}
        for f in fits
        for c, r in zip(f.centers, f.radii)
    ]
    fitted = RobotDescription.model_validate({**base.model_dump(), "control_points": spheres})
    notes = (
        [f"links covered by their visual geometry (they have no collision geometry): {', '.join(geometry.from_visual)}"]
        if geometry.from_visual
        else []
    )
    if args.home is None:
        home, how = propose_home(fitted)
        fitted = RobotDescription.model_validate({**fitted.model_dump(), "home": home})
        notes.append(f"home {home}: {how}")
    return _written(fitted, packages, spheres), fits, notes


def _written(fitted: RobotDescription, packages: dict[str, str], spheres: list[dict]) -> dict:
    """The robot file's content: unset optional keys left out, and every ROS package the URDF's meshes name listed
    (null where it is searched for), so ``env.robot.packages.NAME=PATH`` can set one on any machine."""
    exclude = {"control_points", "packages"} | {k for k in ("mount", "srdf") if getattr(fitted, k) is None}
    named = {name: packages.get(name) for name in [*package_names(fitted.urdf), *packages]}
    out = fitted.model_dump(mode="json", exclude=exclude)
    return {**out, **({"packages": named} if named else {}), "control_points": spheres}


def _draft_home(args, packages: dict[str, str]) -> list[float]:
    """Mid-range, to validate the description before the spheres exist (a joint the URDF lacks gets 0 here, and
    the description's own check names it with the joints it has)."""
    try:
        # a partial description on purpose (mid_range reads only urdf, joints and limits); pydantic's plugin types
        # model_construct as if every required field had to be given
        draft = RobotDescription.model_construct(urdf=args.urdf, joints=args.joints, limits={})  # type: ignore[call-arg]
        return mid_range(draft)
    except (KeyError, ValueError):
        return [0.0] * len(args.joints)


def _check(path: str) -> tuple[dict, list[LinkFit]]:
    data = yaml.safe_load(Path(path).read_text())
    desc = RobotDescription.model_validate(data)
    meshes = collision_meshes(desc.urdf, sorted({cp.link for cp in desc.control_points}), desc.packages)
    by_link: dict[str, list] = {}
    for cp in desc.control_points:
        by_link.setdefault(cp.link, []).append(cp)
    fits = [
        measure(link, meshes[link], [c.offset for c in cps], [c.radius for c in cps])
        for link, cps in by_link.items()
        if link in meshes
    ]
    return data, fits


def _report(fits: list[LinkFit]) -> str:
    lines = [
        f"  {f.link}: {len(f.radii)} spheres, coverage {100 * f.coverage:.2f} %, overshoot max "
        f"{1000 * f.overshoot.max():.1f} mm"
        for f in fits
    ]
    s = summary(fits)
    verdict = "meets" if s["coverage"] >= TARGET else "misses"
    lines.append(
        f"all: {s['spheres']} spheres, coverage {100 * s['coverage']:.2f} % ({verdict} the "
        f"{100 * TARGET:.0f} % target), overshoot mean {1000 * s['overshoot_mean']:.1f} mm, max "
        f"{1000 * s['overshoot_max']:.1f} mm"
    )
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
            description, fits, notes = _fit(args)
            header = (
                f"# @package env.robot\n# {args.name}: written by rmpfusion-fit-spheres ({args.spheres} spheres "
                f"per link, margin {args.margin} m); edit home, limits and the spheres as needed.\n"
            )
            atomic_write_bytes(args.out, (header + yaml.safe_dump(description, sort_keys=False)).encode())
    except (ValueError, OSError, KeyError, ET.ParseError) as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return 2
    print(_report(fits))
    for note in [] if args.check else notes:
        print(note)
    if args.figure:
        print(f"figure: {plot_coverage(args.figure, fits)}")
    if not args.check:
        print(f"robot description: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
