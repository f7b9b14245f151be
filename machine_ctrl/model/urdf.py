"""The few URDF facts the machine description needs beyond Pinocchio's model: the movable
joints with their type and limits (strokes), and the link names. Malformed files and joints
without a stroke are reported in one line as :class:`ConfigError`."""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from machine_ctrl.model.errors import ConfigError

MOVABLE = ('prismatic', 'revolute', 'continuous')


@dataclass(frozen=True)
class Joint:
    name: str
    type: str                            # prismatic | revolute | continuous
    stroke: tuple[float, float] | None   # None for continuous joints
    velocity: float
    effort: float
    child: str = ''                      # the link it moves (its frame is the joint's frame)
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)   # unit <axis xyz>, in that frame (URDF default 1 0 0)


def _error(path: Path, problem: str) -> ConfigError:
    return ConfigError(f'{path}: {problem}')


def _root(path: Path) -> ET.Element:
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise _error(path, f'cannot read URDF: {exc.strerror or exc}') from None
    except ET.ParseError as exc:
        raise _error(path, f'malformed URDF: {exc}') from None
    if root.tag != 'robot':
        raise _error(path, f'malformed URDF: root element is <{root.tag}>, not <robot>')
    return root


def read_links(path: Path) -> set[str]:
    return {link.get('name') for link in _root(path).iter('link')}


def _limit(path: Path, joint: str, limit: ET.Element | None, attr: str, required: bool) -> float | None:
    text = None if limit is None else limit.get(attr)
    if text is None:
        if required:
            problem = 'stroke missing' if attr in ('lower', 'upper') else f'{attr} missing'
            raise _error(path, f'joint {joint}: <limit {attr}=...> {problem}')
        return None
    try:
        value = float(text)
    except ValueError:
        raise _error(path, f'joint {joint}: <limit {attr}="{text}"> is not a number') from None
    if not math.isfinite(value):
        raise _error(path, f'joint {joint}: <limit {attr}="{text}"> is not finite')
    return value


def _axis(path: Path, joint: str, axis: ET.Element | None) -> tuple[float, float, float]:
    """The unit vector of <axis xyz="..."> (1 0 0 when absent, as URDF says)."""
    text = '1 0 0' if axis is None else axis.get('xyz', '1 0 0')
    try:
        xyz = [float(v) for v in text.split()]
    except ValueError:
        xyz = []
    norm = math.sqrt(sum(v * v for v in xyz)) if len(xyz) == 3 and all(map(math.isfinite, xyz)) else 0.0
    if norm == 0.0:
        raise _error(path, f'joint {joint}: <axis xyz="{text}"> is not a non-zero vector of three numbers')
    return tuple(v / norm for v in xyz)


def read_joints(path: Path) -> dict[str, Joint]:
    """Movable joints in file order."""
    root = _root(path)
    links = {link.get('name') for link in root.iter('link')}
    joints = {}
    for element in root.iter('joint'):
        name, kind = element.get('name'), element.get('type')
        if not name:
            raise _error(path, 'malformed URDF: a <joint> has no name')
        for end in ('parent', 'child'):
            link = element.find(end)
            if link is None or link.get('link') not in links:
                raise _error(path, f'malformed URDF: joint {name}: {end} link '
                                   f'{None if link is None else link.get("link")!r} is not a <link>')
        if kind in ('floating', 'planar'):
            raise _error(path, f'joint {name}: type {kind} is not a machine axis')
        if kind not in MOVABLE + ('fixed',):
            raise _error(path, f'joint {name}: unknown type {kind!r}')
        if kind == 'fixed':
            continue
        limit = element.find('limit')
        bounded = kind != 'continuous'
        lower = _limit(path, name, limit, 'lower', bounded)
        upper = _limit(path, name, limit, 'upper', bounded)
        if bounded and not lower < upper:
            raise _error(path, f'joint {name}: stroke lower {lower:g} is not below upper {upper:g}')
        velocity = _limit(path, name, limit, 'velocity', True)
        effort = _limit(path, name, limit, 'effort', True)
        if velocity <= 0 or effort <= 0:
            raise _error(path, f'joint {name}: <limit velocity/effort> must be > 0')
        joints[name] = Joint(name, kind, (lower, upper) if bounded else None, velocity, effort,
                             element.find('child').get('link'), _axis(path, name, element.find('axis')))
    return joints
