"""Machine descriptions: a URDF (kinematic chain, strokes) plus a YAML file (drives, limits,
sensors, control period), loaded into frozen, validated dataclasses.

Every problem stops loading with one line, ``<file>: <key>: <problem>``, raised as
:class:`ConfigError`. Unknown YAML keys are errors too, so a typo never silently falls back
to a default.

Units are SI (m, rad, s, kg, kg*m^2, N, N*m, V). Which values come from which seed is
recorded next to each value in ``config/machines/*.yaml`` / ``*.urdf``.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from machine_ctrl import urdf
from machine_ctrl.errors import ConfigError

DEFAULT_MACHINE = 'micromill_9axis'

DRIVE_TYPES = {
    # type: what the command u is
    'linear_motor': 'V (amplifier input: force = amplifier_gain * force_constant * u)',
    'maglev': 'N or N*m (force/torque on the levitated table)',
    'servo_voltage': 'V (drive identified normalized to its input: u = mass*acc + damping*vel)',
}


@dataclass(frozen=True)
class DriveConfig:
    type: str
    mass: float                      # kg or kg*m^2 (servo_voltage: V*s^2/m or V*s^2/rad)
    damping: float                   # viscous friction per unit velocity
    command_limit: float             # |u| saturation, in the command's unit
    force_constant: float = 1.0      # N/A (linear_motor), else 1
    amplifier_gain: float = 1.0      # A/V (linear_motor), else 1
    command_resolution: float = 0.0  # quantization step of u, 0 = none

    @property
    def gain(self) -> float:
        """Force (or torque) per unit command."""
        return self.force_constant * self.amplifier_gain


@dataclass(frozen=True)
class Limits:
    velocity: float
    acceleration: float
    jerk: float


@dataclass(frozen=True)
class AxisConfig:
    name: str
    kind: str                                # 'linear' (m) or 'rotary' (rad)
    stroke: tuple[float, float] | None       # None: unlimited (continuous joint)
    limits: Limits
    drive: DriveConfig
    sensor_resolution: float
    effort: float                            # actuator peak force/torque from the URDF

    @property
    def unit(self) -> str:
        return 'm' if self.kind == 'linear' else 'rad'

    def in_stroke(self, value: float) -> bool:
        return self.stroke is None or self.stroke[0] <= value <= self.stroke[1]


@dataclass(frozen=True)
class MachineConfig:
    name: str
    description: str
    yaml_path: Path
    urdf_path: Path
    control_period: float
    workpiece_frame: str
    tool_frame: str
    axes: tuple[AxisConfig, ...]
    home: tuple[float, ...]

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    def axis(self, name: str) -> AxisConfig:
        for a in self.axes:
            if a.name == name:
                return a
        raise KeyError(f'{self.name}: no axis {name!r} (axes: {", ".join(self.axis_names)})')


_REQUIRED = object()


class _Section:
    """A YAML mapping being read, remembering its file and key path for error messages."""

    def __init__(self, data: Any, file: Path, key: str):
        self.file, self.key = file, key
        if not isinstance(data, dict):
            self.fail(f'must be a mapping, got {type(data).__name__}')
        self.data = data
        self._used: set[str] = set()

    def fail(self, problem: str, key: str | None = None):
        where = '.'.join(k for k in (self.key, key) if k)
        raise ConfigError(f'{self.file}: {where or "<top>"}: {problem}')

    def _get(self, key: str, default: Any):
        self._used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                self.fail('missing', key)
            return default
        return self.data[key]

    def section(self, key: str) -> _Section:
        return _Section(self._get(key, _REQUIRED), self.file, f'{self.key}.{key}' if self.key else key)

    def string(self, key: str, default: str | None = None, choices=None) -> str:
        if default is not None and key not in self.data:
            self._used.add(key)
            return default
        value = self._get(key, _REQUIRED)
        if not isinstance(value, str) or not value:
            self.fail(f'must be a non-empty string, got {value!r}', key)
        if choices is not None and value not in choices:
            self.fail(f'must be one of {", ".join(sorted(choices))}, got {value!r}', key)
        return value

    def number(self, key: str, default: float | None = None, *, positive=False,
               nonnegative=False) -> float:
        value = self._get(key, _REQUIRED if default is None else default)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(f'must be a number, got {value!r}', key)
        value = float(value)
        if not math.isfinite(value):
            self.fail(f'must be finite, got {value}', key)
        if positive and value <= 0:
            self.fail(f'must be > 0, got {value:g}', key)
        if nonnegative and value < 0:
            self.fail(f'must be >= 0, got {value:g}', key)
        return value

    def finish(self):
        unknown = sorted(set(map(str, self.data)) - self._used)
        if unknown:
            self.fail(f'unknown key(s): {", ".join(unknown)}')


def _drive(s: _Section) -> DriveConfig:
    drive = DriveConfig(
        type=s.string('type', choices=DRIVE_TYPES),
        mass=s.number('mass', positive=True),
        damping=s.number('damping', nonnegative=True),
        command_limit=s.number('command_limit', positive=True),
        force_constant=s.number('force_constant', 1.0, positive=True),
        amplifier_gain=s.number('amplifier_gain', 1.0, positive=True),
        command_resolution=s.number('command_resolution', 0.0, nonnegative=True),
    )
    s.finish()
    return drive


def _limits(s: _Section) -> Limits:
    limits = Limits(*(s.number(k, positive=True) for k in ('velocity', 'acceleration', 'jerk')))
    s.finish()
    return limits


def _axis(s: _Section, name: str, joint: urdf.Joint) -> AxisConfig:
    limits = _limits(s.section('limits'))
    if not math.isclose(joint.velocity, limits.velocity, rel_tol=1e-9):
        s.fail(f'{limits.velocity:g} differs from the URDF joint velocity limit {joint.velocity:g}',
               'limits.velocity')
    axis = AxisConfig(
        name=name,
        kind='linear' if joint.type == 'prismatic' else 'rotary',
        stroke=joint.stroke,
        limits=limits,
        drive=_drive(s.section('drive')),
        sensor_resolution=s.number('sensor_resolution', positive=True),
        effort=joint.effort,
    )
    s.finish()
    return axis


def load_machine(name_or_path: str | Path = DEFAULT_MACHINE) -> MachineConfig:
    """Load a machine by name (``config/machines/<name>.yaml``) or by YAML path."""
    path = resolve_machine(name_or_path)
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f'{path}: cannot read: {_one_line(exc)}') from None
    top = _Section(raw, path, '')
    name = top.string('name')
    description = top.string('description', '')
    urdf_path = (path.parent / top.string('urdf')).resolve()
    joints = urdf.read_joints(urdf_path)
    control_period = top.number('control_period', positive=True)
    frames = top.section('frames')
    workpiece_frame, tool_frame = frames.string('workpiece'), frames.string('tool')
    frames.finish()
    links = urdf.read_links(urdf_path)
    for key, frame in (('workpiece', workpiece_frame), ('tool', tool_frame)):
        if frame not in links:
            frames.fail(f'no link {frame!r} in {urdf_path.name}', key)

    axes_section = top.section('axes')
    if not axes_section.data:
        axes_section.fail('no axes')
    axes = []
    for axis_name in map(str, axes_section.data):
        if axis_name not in joints:
            axes_section.fail(f'unknown axis (no movable joint of that name in {urdf_path.name}; '
                              f'joints: {", ".join(joints) or "none"})', axis_name)
        axes.append(_axis(axes_section.section(axis_name), axis_name, joints[axis_name]))
    axes_section.finish()
    missing = [j for j in joints if j not in axes_section.data]
    if missing:
        axes_section.fail(f'URDF joint(s) without an axis entry: {", ".join(missing)}')

    home = tuple(0.0 for _ in axes)
    if 'home' in top.data:
        home_section = top.section('home')
        home = tuple(home_section.number(a.name, 0.0) for a in axes)
        home_section.finish()
    top.finish()
    for axis, value in zip(axes, home):
        if not axis.in_stroke(value):
            raise ConfigError(f'{path}: home.{axis.name}: {value:g} is outside the stroke {axis.stroke}')
    return MachineConfig(name, description, path, urdf_path, control_period, workpiece_frame,
                         tool_frame, tuple(axes), home)


def config_dirs() -> list[Path]:
    """Where machine descriptions are looked up, first match wins: the source checkout this
    package runs from (editable install), the ament index, then the Python prefix."""
    dirs = []
    source = Path(__file__).resolve().parents[1]
    if (source / 'package.xml').is_file():
        dirs.append(source / 'config')
    try:
        from ament_index_python.packages import get_package_share_directory
        dirs.append(Path(get_package_share_directory('machine_ctrl')) / 'config')
    except Exception:  # noqa: BLE001 - index absent or package not registered: fall through
        pass
    dirs.append(Path(sys.prefix) / 'share' / 'machine_ctrl' / 'config')
    return [d for d in dict.fromkeys(dirs) if d.is_dir()]


def available_machines() -> list[str]:
    return sorted({p.stem for d in config_dirs() for p in (d / 'machines').glob('*.yaml')})


def resolve_machine(name_or_path: str | Path) -> Path:
    text = str(name_or_path)
    if text.endswith(('.yaml', '.yml')) or '/' in text:
        path = Path(text)
        if not path.is_file():
            raise ConfigError(f'{path}: no such machine file')
        return path.resolve()
    for d in config_dirs():
        path = d / 'machines' / f'{text}.yaml'
        if path.is_file():
            return path
    raise ConfigError(f'{text}: unknown machine (available: {", ".join(available_machines()) or "none"})')


def _one_line(exc: BaseException) -> str:
    return ' '.join(str(exc).split())
