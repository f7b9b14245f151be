"""The simulated machine without ROS: every axis's plant and sensor, stepped one control
period at a time with one command per axis, plus the fault logic of the hardware.

A machine with ``simulation.tool_compliance`` (a robot arm) also deflects under the milling
force (hw_sim/tool_deflection.py): :attr:`MachineSimulator.deflection` moves the true tool tip
(:meth:`MachineSimulator.true_tool_pose`), not the axes, so no encoder sees it.

Faults (the machine stops and stays stopped until :meth:`reset`): a non-finite command or a
wrong number of them, a true position outside its stroke after a step, or (raised by the lock-step layer) a
missing command. "Stopped" means drives disabled and axes held where they are: the state is
frozen (the deflection too), velocities read zero. Sensor noise is seeded from the machine config
(simulation.seed), one stream per axis, so a run is reproducible bit for bit.
"""
from __future__ import annotations

import functools
import math
import random
from typing import NamedTuple

import numpy as np

from compensation.error_map import load_error_map
from compensation.error_model import ErrorKinematics
from hw_sim.flexure import Accelerometer, FlexureAxis
from hw_sim.plant import FrictionAxis, LinearAxis, PiezoDriveAxis, PositionServoAxis, Sensor, quantize
from hw_sim.tool_deflection import ToolDeflection, deflected, rigid_tip
from machine_ctrl.model.config import AxisConfig, MachineConfig
from machine_ctrl.model.kinematics import Kinematics


def make_plant(axis: AxisConfig, period: float, substeps: int, rng: random.Random, position: float = 0.0):
    """The plant model of `axis`: a voice-coil flexure stage, a robot joint's closed loop, a
    piezo stage, a friction axis, or linear."""
    if axis.plant is None:
        raise ValueError(f'axis {axis.name}: no plant section in the machine config')
    if axis.drive.type == 'voice_coil':
        return FlexureAxis(axis, period, rng, position)
    if axis.drive.type == 'position_servo':
        return PositionServoAxis(axis, period, rng, position)
    if axis.drive.type == 'piezo':
        return PiezoDriveAxis(axis, period, rng, position)
    if axis.plant.friction is not None:
        return FrictionAxis(axis, period, substeps, rng, position)
    return LinearAxis(axis, period, rng, position)


class Measurement(NamedTuple):       # a NamedTuple: one is made per step (cheaper than a frozen dataclass)
    position: tuple[float, ...]      # encoder / probe readings, axis order
    velocity: tuple[float, ...]      # differentiated readings
    effort: tuple[float, ...]        # commands applied during the previous period
    acceleration: tuple[float, ...] = ()   # accelerometer readings, m/s^2 (0.0 on axes without one)
    tracker: tuple[float, ...] = ()  # the tracker's reading (x, y, z), m, workpiece frame; () without one


class MachineSimulator:
    def __init__(self, machine: MachineConfig, initial_position=None):
        self.machine = machine
        self._strokes = [a.stroke or (-math.inf, math.inf) for a in machine.axes]
        self.initial = tuple(machine.home if initial_position is None else initial_position)
        if len(self.initial) != len(machine.axes):
            raise ValueError(f'initial position needs {len(machine.axes)} values')
        self._tracker = machine.tracker
        # the tracker reads the coarse stage: the true tool tip with the fine axes at home
        self._tracker_home = None if self._tracker is None else [
            (machine.axis_names.index(a), machine.home[machine.axis_names.index(a)])
            for a in machine.cartesian_dual_stage.fine]
        self.reset()

    @functools.cached_property
    def geometry(self):
        """true_geometry(machine), built at its first use (an error map is read then: ConfigError)."""
        return true_geometry(self.machine)

    def true_tool_pose(self) -> np.ndarray:
        """The true 4x4 tool pose in the workpiece frame now: the geometry's at the true axis
        positions, moved by the structure's deflection."""
        return deflected(self.geometry(self.true_position), self.deflection)

    def reset(self, initial_position=None) -> None:
        """Fresh plants and sensors at the initial (or given) position, fault cleared."""
        machine, period = self.machine, self.machine.control_period
        start = self.initial if initial_position is None else tuple(initial_position)
        seed = machine.simulation.seed
        self.plants = [make_plant(a, period, machine.simulation.substeps,
                                  random.Random(f'{seed}:{a.name}:actuator'), q0)
                       for a, q0 in zip(machine.axes, start)]
        self.sensors = [Sensor(a.sensor_resolution, a.plant.sensor_noise, period,
                               random.Random(f'{seed}:{a.name}'), q0)
                        for a, q0 in zip(machine.axes, start)]
        self.accelerometers = [Accelerometer(a, random.Random(f'{seed}:{a.name}:accelerometer'))
                               if a.plant.accelerometer is not None else None for a in machine.axes]
        self._with_accelerometer = any(self.accelerometers)
        self._no_acceleration = (0.0,) * len(machine.axes)
        self.step_index = 0
        self.fault: str | None = None
        self.applied = (0.0,) * len(self.plants)
        compliance = machine.simulation.tool_compliance
        self.compliance = None if compliance is None else ToolDeflection(
            compliance, period, seed, rigid_tip(self.geometry, self.true_position))
        self._tracker_rng = random.Random(f'{seed}:tracker')
        self._measure()

    def _measure(self) -> None:
        position, velocity = zip(*[s.measure(p.sensed) for s, p in zip(self.sensors, self.plants)])
        acceleration = self._no_acceleration if not self._with_accelerometer else \
            tuple([0.0 if a is None else a.measure(p.acceleration_sensed) for a, p in zip(self.accelerometers, self.plants)])
        tracker = () if self._tracker is None else self._tracker_reading()
        self.measurement = Measurement(position, velocity, self.applied, acceleration, tracker)

    def _tracker_reading(self) -> tuple[float, float, float]:
        """The tracker (machine.tracker): the true tool tip with the fine axes at home, the
        structure's deflection included, plus its noise, quantized."""
        q = list(self.true_position)
        for index, home in self._tracker_home:
            q[index] = home
        x, y, z = rigid_tip(self.geometry, tuple(q))
        tracker, rng = self._tracker, self._tracker_rng
        z += self.deflection
        return tuple([quantize(c + (rng.gauss(0.0, tracker.noise) if tracker.noise > 0.0 else 0.0),
                               tracker.resolution) for c in (x, y, z)])

    def set_force(self, axis: str, force: float) -> None:
        """An external force (N) on `axis`'s moving mass from the next step on (the cutting
        force of Ding Eq. 7-7); ValueError for an axis whose plant takes none, or a non-finite force."""
        plant = self.plants[self.machine.axis_names.index(axis)]
        if not hasattr(plant, 'force'):
            raise ValueError(f'axis {axis}: its plant takes no external force (only voice_coil flexure stages)')
        if not math.isfinite(force):
            raise ValueError(f'axis {axis}: force must be finite, got {force!r}')
        plant.force = float(force)

    @property
    def true_position(self) -> tuple[float, ...]:
        return tuple([p.position for p in self.plants])

    @property
    def deflection(self) -> float:
        """m, the true tool tip's displacement along the workpiece's z by the structure's
        compliance (0.0 without tool_compliance)."""
        return 0.0 if self.compliance is None else self.compliance.deflection

    @property
    def true_velocity(self) -> tuple[float, ...]:
        return tuple(p.velocity for p in self.plants)

    def stop(self, reason: str) -> None:
        if self.fault is None:
            self.fault = reason

    def step(self, commands) -> Measurement:
        """Apply one command per axis for one period; return the new measurement."""
        if self.fault is None:
            self.fault = self.command_fault(commands)
        if self.fault is None:
            self.applied = tuple([p.step(u) for p, u in zip(self.plants, commands)])
            true_position = self.true_position
            self.fault = self.stroke_fault(true_position)
            if self.compliance is not None:
                self.compliance.step(rigid_tip(self.geometry, true_position))
        else:
            self.applied = (0.0,) * len(self.plants)
        self.step_index += 1
        if self.fault is None:
            self._measure()
        else:
            held = self.measurement
            zeros = (0.0,) * len(held.position)
            self.measurement = Measurement(held.position, zeros, self.applied, zeros, held.tracker)
        return self.measurement

    def command_fault(self, commands) -> str | None:
        """Why the hardware refuses `commands` (a wrong count, a non-finite value), or None."""
        if len(commands) != len(self.plants):
            return f'{len(commands)} commands for {len(self.plants)} axes'
        if not all(map(math.isfinite, commands)):
            bad = [a.name for a, u in zip(self.machine.axes, commands) if not math.isfinite(u)]
            return f'non-finite command for {", ".join(bad)}'
        return None

    def stroke_fault(self, positions) -> str | None:
        """The first axis whose true position is outside its stroke, or None."""
        for axis, position, (lo, hi) in zip(self.machine.axes, positions, self._strokes):
            if not lo <= position <= hi:
                return (f'stroke violation on {axis.name}: {position:.9g} {axis.unit} '
                        f'outside [{lo:g}, {hi:g}]')
        return None


def true_geometry(machine: MachineConfig, kinematics: Kinematics | None = None):
    """The simulated machine's true tool-pose function q -> 4x4 ^wT_t: the error-augmented
    kinematics of its geometric error map (simulation.error_map), or the ideal kinematics
    when none is configured (bit-identical to Kinematics.tool_pose). ConfigError on a bad map."""
    kinematics = kinematics or Kinematics.from_config(machine)
    path = machine.simulation.error_map_path(machine.yaml_path)
    if path is None:
        return kinematics.tool_pose
    model = ErrorKinematics.from_config(machine, load_error_map(path, machine.axis_names), kinematics)
    return model.tool_pose
