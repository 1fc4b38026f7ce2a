"""A robot description: what rmpfusion needs to know about an arm beyond its URDF, as validated data.

It is the robot's own file (``conf/robot/<name>.yaml``, written by hand or by ``rmpfusion-fit-spheres``): the URDF,
the actuated joints, the end effector, joint limits (the URDF's unless overridden), a home configuration and the
control-point spheres that obstacle barriers keep away from obstacles. The environment simulates the robot from it
and the manipulator tree is generated from it, so both always see the same robot. Every name in it is checked
against the URDF when it is validated, with the closest names offered.
"""

from __future__ import annotations

import difflib
import functools
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from typing import Literal

from pydantic import Field, field_validator, model_validator

from ..maps.robot_params import Mount
from ..maps.urdf import URDFModel, parse_urdf, resolve_urdf_path
from ..registry import Params
from .packages import package_folder

Vec3 = tuple[float, float, float]


def _close(name: str, options: Sequence[str]) -> str:
    found = difflib.get_close_matches(name, list(options), n=3, cutoff=0.5)
    return f"did you mean {', '.join(map(repr, found))}? " if found else ""


@functools.lru_cache(maxsize=32)
def _model(urdf: str) -> URDFModel:
    return parse_urdf(urdf)


class ControlPoint(Params):
    """A sphere fixed to a link: its surface is what the obstacle barriers keep away from obstacles."""

    link: str
    offset: Vec3 = Field((0.0, 0.0, 0.0), description="sphere centre in the link frame (m)")
    radius: float = Field(gt=0, le=2.0, description="sphere radius (m): distances are taken from its surface")


class EndEffector(Params):
    """The point the attractor drives to the goal and at which reaching is measured."""

    link: str
    offset: Vec3 = Field((0.0, 0.0, 0.0), description="the point in the link frame (m)")


class JointLimits(Params):
    """Overrides of one joint's URDF limits; a key left out keeps the URDF's value."""

    lower: float | None = Field(None, ge=-100.0, le=100.0, description="rad (m for a prismatic joint)")
    upper: float | None = Field(None, ge=-100.0, le=100.0, description="rad (m for a prismatic joint)")
    velocity: float | None = Field(None, gt=0, le=100.0, description="rad/s (m/s)")


class HeldJointGains(Params):
    """How a simulated robot holds its movable joints that are not actuated (e.g. fingers) at 0: a PD acceleration
    inside the same inverse dynamics as the arm's command."""

    kp: float = Field(400.0, gt=0, le=1e6, description="1/s²")
    kd: float = Field(40.0, ge=0, le=1e4, description="1/s")


class RobotDescription(Params):
    """A fixed-base arm described by a URDF (the ``urdf`` kind of rmpfusion.registry.ROBOTS)."""

    type: Literal["urdf"] = "urdf"
    name: str = Field(description="how figures and messages name the robot")
    urdf: str = Field(description="a file path, or pkg://<package>/<path> inside an installed Python package")
    packages: dict[str, str | None] = Field(
        default_factory=dict,
        description="ROS package name -> its folder (a "
        "path or pkg://<python package>/<folder>; null: searched for), for the "
        "URDF's package:// meshes (robots/packages.py)",
    )
    mount: Mount | None = Field(
        None, description="where the base sits in the world (xyz m, rpy rad); default the origin"
    )
    srdf: str | None = Field(
        None, description="an SRDF (path or pkg://) whose <disable_collisions> link pairs get no self-collision barrier"
    )
    joints: list[str] = Field(
        min_length=1, description="the actuated joints, in configuration order; other movable joints are held at 0"
    )
    end_effector: EndEffector
    home: list[float] = Field(
        description="a configuration inside the limits (rad), one value per actuated joint: "
        "the centre of the starts unless the experiment says otherwise"
    )
    limits: dict[str, JointLimits] = Field(default_factory=dict, description="per-joint overrides of the URDF limits")
    control_points: list[ControlPoint] = Field(default_factory=list, description="spheres approximating the arm")
    held_joint_gains: HeldJointGains = HeldJointGains()

    @field_validator("urdf")
    @classmethod
    def _readable(cls, v: str) -> str:
        try:
            _model(v)  # a missing or malformed file is said here, with its path
        except FileNotFoundError as e:
            raise ValueError(
                f"{e}; fix urdf: in the robot's file (conf/robot/<name>.yaml or env.robot.urdf=...) to "
                "name a URDF that exists (a path from the working directory, or pkg://<package>/<path>)"
            ) from None
        return v

    @field_validator("packages")
    @classmethod
    def _folders(cls, v: dict[str, str | None]) -> dict[str, str | None]:
        for name, folder in v.items():
            if folder:  # a folder that is not there is said here, not when a mesh is read
                try:
                    package_folder(name, folder)
                except FileNotFoundError as e:
                    raise ValueError(str(e)) from None
        return v

    @model_validator(mode="after")
    def _names_in_the_urdf(self):
        model = _model(self.urdf)
        movable, links = model.movable_joint_names(), model.link_names()
        for i, j in enumerate(self.joints):
            if j not in movable:
                raise ValueError(
                    f"joints[{i}] = {j!r} is not a movable joint of {self.urdf}; {_close(j, movable)}"
                    f"movable joints: {', '.join(movable)}"
                )
            mimic = model.joint(j).mimic
            if mimic is not None:
                raise ValueError(
                    f"joints[{i}] = {j!r} follows {mimic.leader!r} (URDF <mimic>), so it cannot be "
                    f"actuated on its own; list {mimic.leader!r} instead (its followers move with it)"
                )
        if len(set(self.joints)) != len(self.joints):
            raise ValueError(f"joints lists a joint twice: {self.joints}")
        for where, link in [
            ("end_effector.link", self.end_effector.link),
            *((f"control_points[{i}].link", c.link) for i, c in enumerate(self.control_points)),
        ]:
            if link not in links:
                raise ValueError(
                    f"{where} = {link!r} is not a link of {self.urdf}; {_close(link, links)}links: {', '.join(links)}"
                )
        for j in self.limits:
            if j not in self.joints:
                raise ValueError(
                    f"limits.{j}: not an actuated joint; {_close(j, self.joints)}actuated: {', '.join(self.joints)}"
                )
        for a, b in self.disabled_collisions():
            for link in (a, b):
                if link not in links:
                    raise ValueError(
                        f"srdf {self.srdf}: <disable_collisions> names {link!r}, not a link of "
                        f"{self.urdf}; {_close(link, links)}links: {', '.join(links)}"
                    )
        self._check_home()
        return self

    def disabled_collisions(self) -> set[tuple[str, str]]:
        """The link pairs (both orders) the SRDF's ``<disable_collisions>`` exempts from self-collision checks."""
        if self.srdf is None:
            return set()
        path = resolve_urdf_path(self.srdf)
        try:
            root = ET.parse(path).getroot()
        except (OSError, ET.ParseError) as e:
            raise ValueError(f"srdf {self.srdf}: cannot be read ({' '.join(str(e).split())})") from None
        pairs = {(d.get("link1", ""), d.get("link2", "")) for d in root.iter("disable_collisions")}
        return pairs | {(b, a) for a, b in pairs}

    def _check_home(self) -> None:
        if len(self.home) != len(self.joints):
            raise ValueError(f"home has {len(self.home)} values for {len(self.joints)} actuated joints {self.joints}")
        for j, q, (lo, hi, _) in zip(self.joints, self.home, self.joint_limits()):
            if not lo <= q <= hi:
                raise ValueError(f"home: {j} = {q} lies outside its limits [{lo}, {hi}]; move it inside")

    def joint_limits(self) -> list[tuple[float, float, float]]:
        """(lower, upper, velocity) of every actuated joint: the URDF's, with ``limits`` overriding key by key
        (±inf and inf where the URDF gives none, e.g. continuous joints)."""
        model, out = _model(self.urdf), []
        for name in self.joints:
            j, o = model.joint(name), self.limits.get(name, JointLimits())
            lo = j.lower if o.lower is None else o.lower
            hi = j.upper if o.upper is None else o.upper
            vel = j.velocity if o.velocity is None else o.velocity
            if not lo < hi:
                raise ValueError(f"limits.{name}: lower {lo} must be below upper {hi}")
            out.append((lo, hi, vel))
        return out

    def model(self) -> URDFModel:
        return _model(self.urdf)

    def finite_limits(self) -> list[tuple[int, str, float]]:
        """(joint index, side, limit) of every finite position limit: what joint-limit barriers guard."""
        out = []
        for k, (lo, hi, _) in enumerate(self.joint_limits()):
            for side, lim in (("upper", hi), ("lower", lo)):
                if math.isfinite(lim):
                    out.append((k, side, lim))
        return out
