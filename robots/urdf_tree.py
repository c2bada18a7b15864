"""A URDF's links and joints read as a tree from its XML, without Pinocchio: what `robots.load` needs to
pick a tool frame and `python -m robots describe` prints, and where each visual mesh's file is.

    tree = UrdfTree.parse(xml)
    tree.root                      # the link no joint moves
    tree.path("tool0")             # the joints from the root to a link, root first
    tree.children["wrist_3_link"]  # the joints hanging from a link
    resolve_meshes(xml, urdf_dir, package_dirs)   # (xml with meshes found made absolute and the
                                                  #  others' <visual> removed, links missing a mesh)
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

ACTUATED = ("revolute", "continuous", "prismatic")  # one-axis joints: a coordinate of q
MANY_AXES = ("floating", "planar")  # joints of several coordinates, which the lab's model has not


@dataclass(frozen=True)
class Joint:
    name: str
    type: str  # revolute, continuous, prismatic, fixed, floating, planar
    parent: str
    child: str
    lower: float | None
    upper: float | None
    mimic: str | None  # the joint it mimics

    @property
    def actuated(self) -> bool:
        """A one-axis joint that is nobody's mimic: a coordinate of the lab's q."""
        return self.type in ACTUATED and self.mimic is None

    def limits_text(self) -> str:
        if self.type == "continuous":
            return "continuous (one angle in [-pi, pi])"
        if self.lower is None or self.upper is None:
            return "no limits in the URDF"
        unit = "m" if self.type == "prismatic" else "rad"
        return f"[{self.lower:g}, {self.upper:g}] {unit}"


class UrdfTree:
    """Links and joints of one URDF: `joints` by name, `parent_joint` of each child link,
    `children` joints of each link, `root` the link that is nobody's child."""

    def __init__(self, links: list[str], joints: list[Joint]):
        self.links = links
        self.joints = {j.name: j for j in joints}
        self.parent_joint = {j.child: j for j in joints}
        self.children: dict[str, list[Joint]] = {link: [] for link in links}
        for j in joints:
            self.children.setdefault(j.parent, []).append(j)
        roots = [link for link in links if link not in self.parent_joint]
        self.root = roots[0] if roots else (links[0] if links else "")

    @classmethod
    def parse(cls, xml: str) -> "UrdfTree":
        """Raises ValueError on text that is not XML with a <robot> root."""
        try:
            root = ET.fromstring(xml)
        except ET.ParseError as e:
            raise ValueError(f"not XML: {e}") from None
        if root.tag != "robot":
            raise ValueError(f"the XML's root element is <{root.tag}>, not <robot>: not a URDF")
        links = [link.get("name", "") for link in root.findall("link")]
        joints = []
        for j in root.findall("joint"):
            limit, mimic = j.find("limit"), j.find("mimic")
            parent, child = j.find("parent"), j.find("child")
            joints.append(Joint(
                name=j.get("name", ""), type=j.get("type", ""),
                parent=parent.get("link", "") if parent is not None else "",
                child=child.get("link", "") if child is not None else "",
                lower=_float(limit, "lower"), upper=_float(limit, "upper"),
                mimic=mimic.get("joint") if mimic is not None else None))
        return cls(links, joints)

    def path(self, link: str) -> list[Joint]:
        """The joints from the root to `link`, root first (every type, fixed ones included)."""
        out, seen = [], set()
        while link in self.parent_joint and link not in seen:  # `seen`: a broken file's loop ends
            seen.add(link)
            j = self.parent_joint[link]
            out.append(j)
            link = j.parent
        return out[::-1]

    def leaves(self) -> list[str]:
        """Links no joint hangs from, in the file's order."""
        return [link for link in self.links if not self.children.get(link)]


def _float(element, key) -> float | None:
    if element is None or element.get(key) is None:
        return None
    try:
        return float(element.get(key))
    except ValueError:
        return None


def _resolve(filename: str, urdf_dir: str, package_dirs) -> str | None:
    """The file a mesh's filename names, or None: package://pkg/rest under a package dir (or
    ROS_PACKAGE_PATH), file:// and absolute paths as they are, relative paths from the URDF's folder."""
    if filename.startswith("package://"):
        rest = filename[len("package://"):].lstrip("/")  # talos_full: "package:///example-robot-data/..."
        dirs = list(package_dirs) + [d for d in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if d]
        for d in dirs:
            candidate = os.path.join(d, rest)
            if os.path.isfile(candidate):
                return os.path.abspath(candidate)
        return None
    if filename.startswith("file://"):
        filename = filename[len("file://"):]
    candidate = filename if os.path.isabs(filename) else os.path.join(urdf_dir, filename)
    return os.path.abspath(candidate) if os.path.isfile(candidate) else None


def resolve_meshes(xml: str, urdf_dir: str, package_dirs) -> tuple[str, tuple[str, ...]]:
    """(xml whose visual meshes that resolve name their absolute file and whose other mesh visuals are
    removed, the links that lost a visual so, in the file's order). The xml comes back unchanged when
    every mesh resolves; unparsable xml is returned as it is (the URDF parser reports it)."""
    try:
        root = ET.fromstring(xml)
    except ET.ParseError:
        return xml, ()
    missing, changed = [], False
    for link in root.findall("link"):
        for visual in list(link.findall("visual")):
            mesh = visual.find("geometry/mesh")
            if mesh is None:
                continue
            found = _resolve(mesh.get("filename", ""), urdf_dir, package_dirs)
            if found is None:
                link.remove(visual)
                if link.get("name", "") not in missing:
                    missing.append(link.get("name", ""))
                changed = True
            elif not mesh.get("filename", "").startswith("package://"):
                mesh.set("filename", found)
                changed = True
    return (ET.tostring(root, encoding="unicode") if changed else xml), tuple(missing)


def rename_clashing_links(xml: str) -> tuple[str, dict[str, str]]:
    """(xml, {old: new}) with each link that shares its name with a joint renamed NAME_link (Pinocchio's
    buildReducedModel cannot tell such frames apart). The joint keeps its name, and its frame sits where
    the link's did: an end effector named so is still found, as that joint's frame."""
    import re

    links = set(re.findall(r"<link\s+name\s*=\s*[\"']([^\"']+)[\"']", xml))
    joints = set(re.findall(r"<joint\s+name\s*=\s*[\"']([^\"']+)[\"']", xml))
    renamed = {}
    for old in sorted(links & joints):
        new = old + "_link"
        while new in links or new in joints:
            new += "_"
        renamed[old] = new
        q = re.escape(old)
        xml = re.sub(rf"(<link\s+name\s*=\s*[\"']){q}([\"'])", rf"\g<1>{new}\g<2>", xml)
        xml = re.sub(rf"(\blink\s*=\s*[\"']){q}([\"'])", rf"\g<1>{new}\g<2>", xml)
    return xml, renamed
