"""What `python -m robots describe ROBOT [--ee FRAME]` prints: the robot's source and file, its chains from
the root link with their joints (kind and limits) and the frames that end them, the frame the lab picks,
and, with ee=, the arm the lab builds (or why it refuses it). Read from the URDF's XML, so a robot the lab
refuses is described too."""

from __future__ import annotations

from robots import sources
from robots.urdf_tree import UrdfTree


def describe(robot: str, ee=None) -> tuple[str, bool]:
    """(the description as text, whether the lab loads the robot with these frames); ValueError/OSError
    for a robot that names no file (unknown, SDF only)."""
    source, frames = sources.split(robot)
    origin = sources.origin_of(source)
    tree = UrdfTree.parse(origin.xml())
    found = sources.chains(origin, tree)
    lines = [f"robot   {robot}", f"urdf    {origin.urdf}", f"sha256  {sources.file_sha256(origin.urdf)}",
             f"root    {tree.root} (fixed in space)", ""]
    width = max((len(j.name) for c in found for j in c.joints), default=0)
    for k, chain in enumerate(found, 1):
        stop = f", stops before {chain.stops_before.name!r} (a gripper or hand, locked)" if chain.stops_before else ""
        lines.append(f"chain {k}: {len(chain.joints)} joint{'s' * (len(chain.joints) != 1)}{stop}")
        for j in chain.joints:
            note = "  (mimics " + j.mimic + ")" if j.mimic else ""
            lines.append(f"  {j.name:<{width}}  {j.type}  {j.limits_text()}{note}")
        lines.append(f"  frames: {', '.join(chain.frames)}")
    if not found:
        lines.append("no chain: no joint moves any link")
    others = [j for j in tree.joints.values() if j.mimic or j.type not in ("fixed",) and
              not any(j in c.joints for c in found)]
    if others:
        lines.append("")
        lines.append("joints off the chains (locked at the reference posture): "
                     + ", ".join(f"{j.name} ({j.type}{', mimics ' + j.mimic if j.mimic else ''})" for j in others))
    lines.append("")
    given = sources._frames_of(ee, robot) or frames
    if given is None:
        if origin.registered is not None:
            given = sources._registered_frames(origin.registered)
            lines.append(f"tool frame: {', '.join(given)} (registered)")
        elif found:
            lines.append(f"tool frame picked without --ee: {found[0].frames[0]} (end of the longest chain, "
                         f"{len(found[0].joints)} joints)")
            given = (found[0].frames[0],)
    if not given:
        return "\n".join(lines), False
    try:
        arm = sources.load(source, ee=given)
    except ValueError as e:
        lines.append(f"the lab refuses {', '.join(given)}: {e}")
        return "\n".join(lines), False
    lines.append(f"loads as {arm.name!r}: {arm.nq} joints")
    for name, lo, hi, prismatic in zip(arm.joint_names, arm.lower, arm.upper, arm.is_prismatic):
        lines.append(f"  {name:<{width}}  [{lo:.6g}, {hi:.6g}] {'m' if prismatic else 'rad'}")
    if arm.missing_meshes:
        lines.append(f"meshes not found (drawn without them): {', '.join(arm.missing_meshes)}")
    return "\n".join(lines), True
