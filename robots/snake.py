"""Hyper-redundant planar "snake" arms: n equal links, every joint revolute about z.

    snake_urdf(10)        # the URDF text of planar-10: 10 links of 23.375 / 10
    python -m robots.snake   # (re)writes robots/urdf/planar-10.urdf and planar-20.urdf from snake_urdf

The arms mirror robots/urdf/planar.urdf, the paper's three-link arm: base frame at the first
joint, joints theta1 .. thetan turning about z, link i reaching l along x of its frame, the
end-effector frame "ee" l along x of the last link, task axes (0, 1), lengths in the paper's
units, visuals of boxes and cylinders (a sphere at the tip) slightly below z = 0. The links are
equal and sum to the planar arm's reach, 8.625 + 8.625 + 6.125 = 23.375, so the snakes and the
planar arm share a workspace radius; every joint's range is [-pi/2, pi/2]. The end effector is

    p = sum_i l (cos(q_1 + ... + q_i), sin(q_1 + ... + q_i)),    l = 23.375 / n.

The files under robots/urdf/ are this module's output (tests/test_robots.py checks they equal
it); nobody edits them by hand.
"""

from __future__ import annotations

import math
import os

PLANAR_REACH = 8.625 + 8.625 + 6.125  # the paper's planar arm stretched out (Table 1)
SNAKES = {"planar-10": 10, "planar-20": 20}  # registry name -> number of links
URDF_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "urdf")


def _f(x: float) -> str:
    """A number as the URDF writes it: repr (round-trips exactly), without a useless '.0'."""
    s = repr(float(x))
    return s[:-2] if s.endswith(".0") else s


def snake_urdf(n: int, reach: float = PLANAR_REACH, name: str | None = None) -> str:
    """URDF text of a planar snake of n equal links of total length `reach`, joints in [-pi/2, pi/2]."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"a snake needs a whole number of links >= 1, got {n!r}")
    if not (math.isfinite(reach) and reach > 0):
        raise ValueError(f"reach must be a positive length, got {reach!r}")
    name = name or f"planar-{n}"
    l = reach / n
    half = math.pi / 2
    # link widths taper from the planar arm's first link (0.8) to its last (0.6), capped by the link
    # length so that a short link does not look like a disc
    lines = [
        '<?xml version="1.0"?>',
        "<!--",
        f"  {name}: a hyper-redundant planar arm of {n} equal links of {_f(l)} (total {_f(reach)},",
        "  the paper's planar arm stretched out). Written by robots/snake.py (snake_urdf); do not edit.",
        "  Base frame at the first joint; every joint turns about z within [-pi/2, pi/2]; the end",
        '  effector ("ee") sits one link length along x of the last link:',
        "    p = sum_i l (cos(q1 + ... + qi), sin(q1 + ... + qi)),  z = 0.",
        "  Units are the paper's; visuals sit slightly below z = 0.",
        "-->",
        f'<robot name="{name}">',
        '  <material name="base"><color rgba="0.25 0.25 0.28 1"/></material>',
        '  <material name="link"><color rgba="0.95 0.55 0.15 1"/></material>',
        '  <material name="joint"><color rgba="0.2 0.35 0.6 1"/></material>',
        '  <material name="tool"><color rgba="0.85 0.1 0.1 1"/></material>',
        "",
        '  <link name="base">',
        '    <visual><origin xyz="0 0 -1.2" rpy="0 0 0"/><geometry><cylinder radius="1.6" length="1.6"/></geometry>'
        '<material name="base"/></visual>',
        "  </link>",
    ]
    for i in range(1, n + 1):
        width = min(0.8 - 0.2 * (i - 1) / max(n - 1, 1), 0.6 * l)
        radius = min(0.9 - 0.2 * (i - 1) / max(n - 1, 1), 0.45 * l)
        lines += [
            f'  <link name="link{i}">',
            f'    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><cylinder radius="{radius:.4f}" length="1.0"/>'
            '</geometry><material name="joint"/></visual>',
            f'    <visual><origin xyz="{_f(l / 2)} 0 0" rpy="0 0 0"/><geometry><box size="{_f(l)} {width:.4f} 0.5"/>'
            '</geometry><material name="link"/></visual>',
            "  </link>",
        ]
    lines += [
        '  <link name="ee">',
        f'    <visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><sphere radius="{min(0.45, 0.3 * l):.4f}"/>'
        '</geometry><material name="tool"/></visual>',
        "  </link>",
        "",
    ]
    for i in range(1, n + 1):
        parent = "base" if i == 1 else f"link{i - 1}"
        x = "0" if i == 1 else _f(l)
        lines += [
            f'  <joint name="theta{i}" type="revolute">',
            f'    <parent link="{parent}"/><child link="link{i}"/>',
            f'    <origin xyz="{x} 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>',
            f'    <limit lower="{_f(-half)}" upper="{_f(half)}" effort="10" velocity="2"/>',
            "  </joint>",
        ]
    lines += [
        '  <joint name="ee_joint" type="fixed">',
        f'    <parent link="link{n}"/><child link="ee"/>',
        f'    <origin xyz="{_f(l)} 0 0" rpy="0 0 0"/>',
        "  </joint>",
        "</robot>",
        "",
    ]
    return "\n".join(lines)


def urdf_path(name: str, directory: str = URDF_DIR) -> str:
    return os.path.join(directory, f"{name}.urdf")


def write_urdfs(directory: str = URDF_DIR) -> list[str]:
    """Write every registered snake's URDF (SNAKES) under `directory`; returns the paths."""
    paths = []
    for name, n in SNAKES.items():
        path = urdf_path(name, directory)
        with open(path, "w", encoding="utf-8") as f:
            f.write(snake_urdf(n, name=name))
        paths.append(path)
    return paths


if __name__ == "__main__":
    for p in write_urdfs():
        print("wrote", p)
