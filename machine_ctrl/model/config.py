"""Machine descriptions: a URDF (kinematic chain, strokes) plus a YAML file (drives, limits,
sensors, control period), loaded into frozen, validated dataclasses.

Every problem stops loading with one line, ``<file>: <key>: <problem>``, raised as
:class:`ConfigError`. Unknown YAML keys are errors too, so a typo never silently falls back
to a default.

Units are SI (m, rad, s, kg, kg*m^2, N, N*m, V). Which values come from which seed is
recorded next to each value in ``config/machines/*.yaml`` / ``*.urdf``.
"""
from __future__ import annotations

import copy
import math
import re
import sys
import types
import typing
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, Sequence

import yaml

from machine_ctrl.model import urdf
from machine_ctrl.model.errors import ConfigError

DEFAULT_MACHINE = 'micromill_9axis'

DRIVE_TYPES = {
    # type: what the command u is
    'linear_motor': 'V (amplifier input: force = amplifier_gain * force_constant * u)',
    'maglev': 'amplifier command (force/torque = amplifier_gain * u on the levitated table)',
    'servo_voltage': 'V (drive identified normalized to its input: u = mass*acc + damping*vel)',
    'voice_coil': 'V (DAC volts into the current loop plant.current_loop: force = force_constant * current)',
    'position_servo': 'm or rad (the position reference of a drive whose own controller closes the loop, '
                      'plant.servo: an industrial robot\'s joint)',
    'piezo': 'm (the reference of the inner loop around a piezo-actuator, scaled to the stage\'s displacement: '
             'modes from reference to position, unit static gain; drive.modes the controllers\' model, plant.modes '
             'the truth)',
}
# drive types whose plant is given by its own closed loop: no mass, no damping of their own
CLOSED_LOOP_DRIVES = ('position_servo', 'piezo')
# drives hw_sim simulates as a rigid body under a force: the plant's mass and damping are the truth
RIGID_BODY_DRIVES = ('linear_motor', 'maglev', 'servo_voltage')
# drives whose plant has a mass and damping of its own (the truth; the drive's are the belief)
TRUE_BODY_DRIVES = (*RIGID_BODY_DRIVES, 'voice_coil')


def _positive(**kw):
    return field(metadata={'check': 'positive'}, **kw)


def _nonnegative(**kw):
    return field(metadata={'check': 'nonnegative'}, **kw)


@dataclass(frozen=True)
class DriveConfig:
    type: str = field(metadata={'choices': tuple(DRIVE_TYPES)})
    command_limit: float = _positive()                  # |u| saturation, in the command's unit
    mass: float | None = _positive(default=None)        # kg or kg*m^2 (servo_voltage: V*s^2/m or V*s^2/rad);
                                                        # None for CLOSED_LOOP_DRIVES, required otherwise
    damping: float | None = _nonnegative(default=None)  # viscous friction per unit velocity (as mass)
    force_constant: float = _positive(default=1.0)      # N/A (linear_motor), else 1
    amplifier_gain: float = _positive(default=1.0)      # A/V (linear_motor), else 1
    command_resolution: float = _nonnegative(default=0.0)  # quantization step of u, 0 = none
    # piezo drives: the controllers' model of the axis (its law designs from it), as plant.modes
    # and plant.real_pole, which are the truth hw_sim simulates (README "Truth and belief")
    modes: tuple[ModeConfig, ...] = ()
    real_pole: float = _nonnegative(default=0.0)        # rad/s (0: none)
    # voice_coil drives: the controllers' model of the flexure (the H2 law designs from it, with
    # the drive's mass and damping), as plant.flexure, the truth
    flexure: FlexureConfig | None = None

    @property
    def gain(self) -> float:
        """Force (or torque) per unit command."""
        return self.force_constant * self.amplifier_gain


@dataclass(frozen=True)
class Limits:
    velocity: float = _positive()
    acceleration: float = _positive()
    jerk: float = _positive()


@dataclass(frozen=True)
class FrictionConfig:
    """Plant friction of a linear-motor axis: LuGre bristle dynamics (thesis Eqs. 4.58,
    4.62) whose steady state is the asymmetric Stribeck curve of Eq. (4.41), with the
    magnitude varying sinusoidally along the stroke. Pairs are (positive, negative direction)
    magnitudes."""
    static: tuple[float, float] = _nonnegative()     # N, F_stat
    coulomb: tuple[float, float] = _nonnegative()    # N, F_coul
    omega1: tuple[float, float] = _positive()        # m/s, Stribeck decay of static friction
    omega2: tuple[float, float] = _positive()        # m/s, rise of Coulomb friction
    sigma0: float = _positive()               # N/m, bristle stiffness
    sigma1: float = _nonnegative()            # N*s/m, bristle damping
    variation: float = _nonnegative(default=0.0)            # relative amplitude along the stroke
    variation_wavelength: float = _positive(default=1.0)    # m


@dataclass(frozen=True)
class ModeConfig:
    omega: float = _positive()                # rad/s
    zeta: float = _positive()


@dataclass(frozen=True)
class FlexureConfig:
    """A flexure-guided stage with a second mass hung on it (Ding thesis Fig. 5-4, Eqs. 5-4..5-7
    with k1 rigid): the stage's mass on the flexure (stiffness to the frame, the stage's damping
    as its damping: the plant's mass and damping in hw_sim's truth, the drive's in the
    controllers' model), the secondary mass coupled to it by a spring and a damper."""
    stiffness: float = _positive()             # k2, N/m, flexure to the frame
    secondary_mass: float = _positive()        # m4, kg
    secondary_stiffness: float = _positive()   # k4, N/m
    secondary_damping: float = _nonnegative()  # c4, N*s/m


@dataclass(frozen=True)
class NoiseConfig:
    """A seeded stationary (or integrated) noise given by its one-sided amplitude spectrum
    |W(j w)| = density |(s + corner)/s| |peak(s)| (Ding thesis Eqs. 6-6..6-8 have this form):
    `density` per sqrt(Hz) of the signal's unit, `corner` (rad/s, 0: white) the corner of
    an integrator that makes the low frequencies grow as 1/f, `peak` a resonance (Yuen Eq. 4.76's
    form, as NotchConfig: zeta_num/zeta_den the gain at omega), `rolloff` (rad/s, 0: none) a first-order
    low-pass r/(s + r) above the fitted band (a displacement whose velocity must be finite)."""
    density: float = _positive()
    corner: float = _nonnegative(default=0.0)
    peak: NotchConfig | None = None
    rolloff: float = _nonnegative(default=0.0)


@dataclass(frozen=True)
class AccelerometerConfig:
    """A piezo accelerometer on a flexure stage's moving mass, through its conditioning
    low-pass into an ADC channel (Ding thesis section 7.5.1, Table 7-2): the reading in
    volts is sensitivity (acceleration + noise) after the low-pass, plus the channel's
    per-sample noise, clipped to +-range and quantized to resolution."""
    sensitivity: float = _positive()           # V per m/s^2
    bandwidth: ModeConfig                      # conditioning low-pass (2nd order)
    range: float = _positive()                 # V, the ADC's input range +-range
    resolution: float = _nonnegative(default=0.0)     # V, ADC step
    sample_noise: float = _nonnegative(default=0.0)   # V, std per sample (ADC)
    noise: NoiseConfig | None = None           # m/s^2 per sqrt(Hz), the sensor's own, before the low-pass


@dataclass(frozen=True)
class PlantConfig:
    """What hw_sim simulates beyond the drive (gain, saturation, quantization). The drive's
    mass and damping are the controllers' belief (what their laws are designed from); the
    plant's are the truth hw_sim simulates, required in a plant section of TRUE_BODY_DRIVES
    (README "Truth and belief")."""
    mass: float | None = _positive(default=None)      # as DriveConfig.mass
    damping: float | None = _nonnegative(default=None)   # as DriveConfig.damping
    friction: FrictionConfig | None = None    # linear motors
    resonance: ModeConfig | None = None       # flexible table modes (lightly damped poles ...
    antiresonance: ModeConfig | None = None   # ... and zeros), DC gain 1
    sensor_noise: float = _nonnegative(default=0.0)   # m or rad, std of additive noise
    force_noise: float = _nonnegative(default=0.0)    # N or N*m, std of a white actuator
                                                      # force disturbance held over each period
    # flexure stages (voice_coil drives):
    flexure: FlexureConfig | None = None
    current_loop: ModeConfig | None = None    # closed current loop, DC gain amplifier_gain A/V
    loop_delay: float = _nonnegative(default=0.0)     # s, sensor sample -> command applied (< period)
    sensor_bandwidth: ModeConfig | None = None   # 2nd-order low-pass of the position sensor
    sensor_noise_density: NoiseConfig | None = None   # m/sqrt(Hz) at the sensor, before its low-pass
    current_noise: NoiseConfig | None = None  # A/sqrt(Hz) added to the current
    accelerometer: AccelerometerConfig | None = None  # on the moving mass (acceleration feedback)
    ground_vibration: NoiseConfig | None = None   # m/sqrt(Hz), the frame's motion at the flexure's root
    # position_servo drives: the closed joint loop x'' = w^2 (u - x) - 2 zeta w x'
    servo: ModeConfig | None = None
    # piezo drives: reference -> position, prod_i w_i^2 / (s^2 + 2 zeta_i w_i s + w_i^2) [x p / (s + p)]
    modes: tuple[ModeConfig, ...] = ()
    real_pole: float = _nonnegative(default=0.0)     # p, rad/s (0: none)


@dataclass(frozen=True)
class SlidingModeGains:
    """Thesis Eqs. (4.47)-(4.57)."""
    bandwidth: float = _positive()            # lambda, 1/s
    gain: float = _positive()                 # K_s, V*s/m (V*s/rad)
    adaptation: float = _nonnegative()        # rho, V/m (V/rad)
    disturbance_bounds: tuple[float, float] = (0.0, 0.0)   # d-, d+ in V


@dataclass(frozen=True)
class LuGreFeedforwardGains:
    """Thesis Eqs. (4.58)-(4.67) with g(v) = F_c + (F_s - F_c) exp(-|v|/Omega_s)."""
    sigma0: float = _positive()               # N/m
    sigma1: float = _nonnegative()            # N*s/m
    coulomb: float = _nonnegative()           # F_c, N
    static: float = _nonnegative()            # F_s, N
    stribeck_velocity: float = _positive()    # Omega_s, m/s


@dataclass(frozen=True)
class PPIGains:
    """CIRP paper Eq. (13): P position loop cascaded with a PI velocity loop."""
    position_gain: float = _positive()        # K_p, 1/s
    velocity_gain: float = _positive()        # K_v, V*s/m
    velocity_integral_gain: float = _nonnegative()   # K_vi, V/m


@dataclass(frozen=True)
class NotchConfig:
    """(s^2 + 2 zeta_num omega s + omega^2) / (s^2 + 2 zeta_den omega s + omega^2), Eq. (4.76)."""
    omega: float = _positive()
    zeta_num: float = _positive()
    zeta_den: float = _positive()


@dataclass(frozen=True)
class LeadLagGains:
    """Thesis Eqs. (4.73)-(4.76): K (1 + alpha T s)/(1 + T s) (1 + K_i/s) N(s)."""
    gain: float = _positive()                 # K_f, command unit per m (rad)
    alpha: float = _positive()
    time_constant: float = _positive()        # T, s
    integral: float = _nonnegative()          # K_i, rad/s
    notches: tuple[NotchConfig, ...] = ()


@dataclass(frozen=True)
class PIDGains:
    """Ding thesis Fig. 5-11 / Eq. (7-8): parallel PID with a filtered derivative acting on the
    sensor's volts, K_p + K_i/s + K_d s/(T_f s + 1), e_v = sensitivity (x_r - x); with the
    cascade acceleration loop of Fig. 7-6 / Eq. (7-7) when acceleration_gain > 0."""
    proportional: float = _nonnegative()     # K_p, V/V
    integral: float = _nonnegative()         # K_i, V/(V*s)
    derivative: float = _nonnegative()       # K_d, V*s/V
    derivative_filter: float = _positive()   # T_f, s
    sensitivity: float = _positive()         # S, V/m (V/rad): sensor volts per unit of error
    acceleration_gain: float = _nonnegative(default=0.0)   # K_a, V/V, Eq. (7-7) (0: no acceleration loop)
    accelerometer_sensitivity: float = _nonnegative(default=0.0)   # H_acc at DC, V per m/s^2 (> 0 with K_a > 0)
    acceleration_filter: float = _nonnegative(default=0.0)  # rad/s, corner of a first-order H_a (0: H_a = 1)


@dataclass(frozen=True)
class H2Gains:
    """Ding thesis section 6.3: the weights of the H2-optimal design (machine_ctrl/control/h2.py),
    W_e = (s/M_s + w_b)/(s + w_b eps) on the tool position (Eq. 6-3) and
    W_u = (s + w_bu/M_u)/(eps_u s + w_bu) on the command (Eq. 6-5); the disturbance weights
    are the axis's plant noise models (Eqs. 6-6, 6-7)."""
    bandwidth: float = _positive()           # w_b, rad/s, Eq. (6-3)
    peak: float = _positive()                # M_s, Eqs. (6-3), (6-4)
    epsilon: float = _positive()             # eps, Eq. (6-3)
    control_weight: float = _positive()      # M_u, Eq. (6-5)
    control_bandwidth: float = _positive()   # w_bu, rad/s, Eq. (6-5)
    control_epsilon: float = _positive()     # eps_u, Eq. (6-5)
    error_unit: float = _positive()          # m per unit of the weighted position error
    noise_pole: float = _positive()          # rad/s: the 1/s of a noise filter becomes 1/(s + noise_pole)


@dataclass(frozen=True)
class PositionCommandGains:
    """A position_servo drive's command: its position reference plus a lead on the
    reference velocity, u = x_r + T_v v_r (machine_ctrl/control/position_command.py)."""
    velocity_lead: float = _nonnegative()    # T_v, s (2 zeta / w of plant.servo: no lag on a ramp)


@dataclass(frozen=True)
class LqgGains:
    """Sörnmo section 2.4 (machine_ctrl/control/lqg.py): LQ state feedback with the integral
    state (2.9), l_r for unit static gain, the Kalman filter with the disturbance state (2.8),
    the reference notch, designed from the controllers' model of the axis (drive.modes) in its
    balanced realization at the control period."""
    state_weight: float = _positive()        # Q = state_weight I, Eq. (2.5)
    control_weight: float = _positive()      # R, Eq. (2.5)
    process_noise: float = _positive()       # the model's input disturbance, std per period, command unit
    notch_frequency: float = _nonnegative()  # Hz, the reference notch's centre (0: none)
    notch_width: float = _positive(default=0.5)   # 2 zeta of the notch's poles (control/lqg.py notch); assumed
                                                  # default: -3 dB over ~ +-25 % of the centre, the thesis states none


def _law_gains():
    """A gains section of ControlConfig whose field name is a control law's name."""
    return field(default=None, metadata={'law': True})


@dataclass(frozen=True)
class ControlConfig:
    """One axis's servo: `law` names the gains section in use. The _law_gains() fields are the
    one list of law names (CONTROL_LAWS); machine_ctrl/control/registry.py maps each name to
    its implementation. A new law adds its gains dataclass and a field here."""
    law: str                                 # one of CONTROL_LAWS, checked by _control
    sliding_mode: SlidingModeGains | None = _law_gains()
    lugre_feedforward: LuGreFeedforwardGains | None = None   # friction feed-forward, added to the
                                                             # laws registered with it (sliding_mode, ppi)
    ppi: PPIGains | None = _law_gains()
    lead_lag: LeadLagGains | None = _law_gains()
    pid: PIDGains | None = _law_gains()
    h2: H2Gains | None = _law_gains()
    position_command: PositionCommandGains | None = _law_gains()
    lqg: LqgGains | None = _law_gains()

    @property
    def gains(self):
        """The gains of the law in use."""
        return getattr(self, self.law)


CONTROL_LAWS = tuple(f.name for f in fields(ControlConfig) if f.metadata.get('law'))


@dataclass(frozen=True)
class DualStagePair:
    coarse: str
    fine: str
    sign: float      # fine reference += sign * coarse tracking error (seed-notes.md: z needs -1)


@dataclass(frozen=True)
class TrackerConfig:
    """A tracking system that measures the coarse stage's tool-tip position, deflection and all
    (Sörnmo §2.4-2.5, Fig. 2.9): once per control period, each coordinate with white noise and
    quantized to its resolution (hw_sim/simulator.py)."""
    resolution: float = _nonnegative(default=0.0)    # m
    noise: float = _nonnegative(default=0.0)         # m RMS per reading and coordinate


@dataclass(frozen=True)
class MidRangingConfig:
    """Mid-ranging of a Cartesian coupling (Sörnmo Ch. 3, the VPC structure of Fig. 3.2): the
    coarse stage slowly takes over the fine stage's offset so that the fine stage returns to
    its home, the middle of its stroke (machine_ctrl/control/dual_stage.py).
    `time_constant`: of the desired first-order take-over, T_s(s) = 1/(time_constant s + 1);
    above the control period (the discrete take-over h/T per step below 1)."""
    time_constant: float = _positive()     # s


@dataclass(frozen=True)
class CartesianCoupling:
    """A coarse stage of several axes and a fine stage of others (Sörnmo Fig. 2.9: a robot and
    a micro manipulator): the tool's deviation caused by the coarse axes' tracking errors,
    J_coarse (r_c - x_c), is cancelled by the fine axes, J_fine dq_f = J_coarse (r_c - x_c),
    in the least-squares sense over the tool-tip position (machine_ctrl/control/dual_stage.py).
    With a `tracker` the deviation is measured instead: the tool tip of the reference with the
    fine axes at home, minus the tracker's reading of the coarse stage's. The fine axes only
    compensate: a path plan holds them at home (a joint goal may jog them). With `midranging`
    the coarse axes get offsets too, which move the fine stage's offset over to them."""
    coarse: tuple[str, ...]
    fine: tuple[str, ...]
    tracker: TrackerConfig | None = None
    midranging: MidRangingConfig | None = None


@dataclass(frozen=True)
class ContourChannelGains:
    """The PI compensator of one contour-error channel of the cross-coupled contour control
    (machine_ctrl/control/contour_coupling.py): correction = k_p eps + k_i integral(eps)."""
    proportional: float = _nonnegative()      # k_p, 1
    integral: float = _nonnegative()          # k_i, 1/s


@dataclass(frozen=True)
class ContourControlConfig:
    """Cross-coupled contour control (machine_ctrl/control/contour_coupling.py): the live
    contour-error estimates fed back to the reference of `axes` through the kinematics.
    `tool_tip` acts through the linear axes among `axes`, `orientation` (None: no orientation
    channel) through the rotary ones; `fade`: the time constant with which the correction goes
    to zero while the estimate is invalid or the control is switched off."""
    axes: tuple[str, ...]
    tool_tip: ContourChannelGains
    orientation: ContourChannelGains | None = None
    estimator: str = field(default='compensated', metadata={'choices': ('basic', 'shifted', 'compensated')})
    fade: float = _positive(default=0.01)     # s


@dataclass(frozen=True)
class FaceMillingConfig:
    """The cut that loads a compliant machine's tool (hw_sim/tool_deflection.py): a block of
    material on the workpiece's face (the workpiece frame's xy plane, its finished face at z =
    0, `depth` of material above it), cut by a tool of `tool_radius` fed along the face."""
    interaction_stiffness: float = _positive()    # K_f, N/m, Eq. (5.3)
    removal: float = _positive()                  # D_f, N s/m, Eqs. (5.3)-(5.4): force = D_f v
    depth: float = _positive()                    # m, the layer cut above the finished face
    tool_radius: float = _positive()              # m
    block_x: tuple[float, float]                  # m, the block's extent on the face, low < high
    block_y: tuple[float, float]                  # m
    tooth_frequency: float = _positive()          # Hz, flutes x spindle speed
    ripple: float = _nonnegative(default=0.0)     # relative force swing at the tooth frequency
    variation: float = _nonnegative(default=0.0)  # relative RMS of each tooth's force (seeded)


@dataclass(frozen=True)
class ToolComplianceConfig:
    """The compliance of a machine whose structure deflects under the process force (a robot
    arm, Sörnmo Ch. 4): one mode along the face normal (the workpiece frame's z), stiffness
    k(x) = stiffness + stiffness_variation sin(2 pi x / stiffness_wavelength) along the face's
    x, modal mass stiffness / (2 pi eigenfrequency)^2, `damping` of critical
    (hw_sim/tool_deflection.py)."""
    stiffness: float = _positive()                # N/m
    stiffness_variation: float = _nonnegative()   # N/m
    stiffness_wavelength: float = _positive()     # m
    eigenfrequency: float = _positive()           # Hz
    damping: float = _nonnegative()               # 1
    milling: FaceMillingConfig


@dataclass(frozen=True)
class SimulationConfig:
    seed: int = 0             # seeds every random source of hw_sim
    substeps: int = 1         # plant integration steps per control period (nonlinear plants)
    error_map: str | None = None   # true geometric errors (path relative to the YAML file;
                                   # compensation/error_map.py), None: an ideal machine
    tool_compliance: ToolComplianceConfig | None = None   # the structure's deflection under the
                                   # cutting force, seen by the true tool tip (not by the encoders)

    def error_map_path(self, yaml_path: Path) -> Path | None:
        return None if self.error_map is None else (yaml_path.parent / self.error_map).resolve()


@dataclass(frozen=True)
class AxisConfig:
    name: str
    kind: str                                # 'linear' (m) or 'rotary' (rad)
    stroke: tuple[float, float] | None       # None: unlimited (continuous joint)
    limits: Limits
    drive: DriveConfig
    sensor_resolution: float
    effort: float                            # actuator peak force/torque from the URDF
    plant: PlantConfig | None = None         # None: this axis cannot be simulated
    control: ControlConfig | None = None     # None: no servo law configured
    link: str = ''                           # the URDF link the axis moves (frame of its accelerometer)
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)   # the joint axis in that link's frame, unit

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
    dual_stage: tuple[DualStagePair, ...] = ()
    simulation: SimulationConfig = SimulationConfig()
    cartesian_dual_stage: CartesianCoupling | None = None
    contour_control: ContourControlConfig | None = None

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    @property
    def planned_axes(self) -> tuple[str, ...]:
        """The axes the trajectory planner moves: all but a Cartesian coupling's fine axes,
        which only compensate (held at home by the plan)."""
        held = self.cartesian_dual_stage.fine if self.cartesian_dual_stage is not None else ()
        return tuple(n for n in self.axis_names if n not in held)

    @property
    def fine_axes(self) -> tuple[str, ...]:
        """The fine stage's axes, in coupling order: the pairs' fine axes, then a Cartesian
        coupling's."""
        cartesian = self.cartesian_dual_stage.fine if self.cartesian_dual_stage is not None else ()
        return tuple(p.fine for p in self.dual_stage) + cartesian

    @property
    def offset_axes(self) -> tuple[str, ...]:
        """The axes whose reference the dual-stage coupling offsets each step, in the order of
        its offsets (/dual_stage/offsets): the fine axes, then with mid-ranging the coarse axes
        of the Cartesian coupling."""
        cartesian = self.cartesian_dual_stage
        midranged = cartesian.coarse if cartesian is not None and cartesian.midranging is not None else ()
        return self.fine_axes + midranged

    @property
    def tracker(self) -> TrackerConfig | None:
        """The tracking system of a Cartesian coupling, or None."""
        return self.cartesian_dual_stage.tracker if self.cartesian_dual_stage is not None else None

    @property
    def accelerometer_axes(self) -> tuple[AxisConfig, ...]:
        """The axes with an accelerometer on their moving mass (plant.accelerometer)."""
        return tuple(a for a in self.axes if a.plant is not None and a.plant.accelerometer is not None)

    def axis(self, name: str) -> AxisConfig:
        for a in self.axes:
            if a.name == name:
                return a
        raise KeyError(f'{self.name}: no axis {name!r} (axes: {", ".join(self.axis_names)})')


_REQUIRED = object()


class _Loader(yaml.SafeLoader):
    """YAML 1.2 floats: PyYAML (YAML 1.1) would read ``9.0e5`` (no exponent sign) as a string."""


_Loader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:\d[\d_]*\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$|^[-+]?\.(?:inf|Inf|INF)$|^\.(?:nan|NaN|NAN)$'),
    list('-+0123456789.'))


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


def _read(s: _Section, cls):
    """Read dataclass ``cls`` from section ``s`` by its field names and type hints: floats
    (checked by the field's metadata), number pairs, nested dataclasses (optional when the
    default is None) and tuples of dataclasses. Unknown keys are errors."""
    hints = typing.get_type_hints(cls)
    values = {f.name: _value(s, f, hints[f.name]) for f in fields(cls)
              if f.name in s.data or f.default is MISSING}
    s.finish()
    return cls(**values)


def _value(s: _Section, f, hint):
    """One field; only called when the key is present or required (then `missing`)."""
    name = f.name
    if isinstance(hint, types.UnionType):            # X | None
        hint = next(h for h in typing.get_args(hint) if h is not type(None))
    if hint is float:
        check = f.metadata.get('check')
        return s.number(name, positive=check == 'positive', nonnegative=check == 'nonnegative')
    if hint is int:
        value = s.number(name, nonnegative=True)
        if value != int(value):
            s.fail(f'must be a whole number, got {value:g}', name)
        return int(value)
    if hint is str:
        return s.string(name, choices=f.metadata.get('choices'))
    if is_dataclass(hint):
        return _read(s.section(name), hint)
    args = typing.get_args(hint)
    raw = s._get(name, _REQUIRED)
    if not isinstance(raw, (list, tuple)):
        s.fail(f'must be a list, got {raw!r}', name)
    if args and is_dataclass(args[0]):              # tuple[Dataclass, ...]
        return tuple(_read(_Section(item, s.file, f'{s.key}.{name}[{i}]'), args[0])
                     for i, item in enumerate(raw))
    if len(raw) != 2:                                # tuple[float, float]
        s.fail(f'must be a pair of numbers, got {raw!r}', name)
    pair = _Section({'0': raw[0], '1': raw[1]}, s.file, f'{s.key}.{name}')
    check = f.metadata.get('check')
    return tuple(pair.number(k, positive=check == 'positive', nonnegative=check == 'nonnegative')
                 for k in ('0', '1'))


def _control(s: _Section) -> ControlConfig:
    s.string('law', choices=CONTROL_LAWS)           # first: a bad law name is the error reported
    control = _read(s, ControlConfig)
    if control.gains is None:
        s.fail(f'law {control.law} needs its gains section {control.law!r}')
    return control


def _axis(s: _Section, name: str, joint: urdf.Joint) -> AxisConfig:
    limits = _read(s.section('limits'), Limits)
    if not math.isclose(joint.velocity, limits.velocity, rel_tol=1e-9):
        s.fail(f'{limits.velocity:g} differs from the URDF joint velocity limit {joint.velocity:g}',
               'limits.velocity')
    axis = AxisConfig(
        name=name,
        kind='linear' if joint.type == 'prismatic' else 'rotary',
        stroke=joint.stroke,
        limits=limits,
        drive=_read(s.section('drive'), DriveConfig),
        sensor_resolution=s.number('sensor_resolution', positive=True),
        effort=joint.effort,
        plant=_read(s.section('plant'), PlantConfig) if 'plant' in s.data else None,
        control=_control(s.section('control')) if 'control' in s.data else None,
        link=joint.child,
        direction=joint.axis,
    )
    s._used.update(('plant', 'control'))
    s.finish()
    return axis


# what a belief file may set, per axis: a rigid-body drive's mass and damping, a flexure stage's
# (and its flexure), a piezo drive's model, the numbers of the axis's law
BELIEF_KEYS = ('drive.mass', 'drive.damping', 'drive.flexure', 'drive.modes', 'drive.real_pole', 'control')
BELIEF_DRIVE_KEYS = {**{drive: ('mass', 'damping') for drive in RIGID_BODY_DRIVES},
                     'voice_coil': ('mass', 'damping', 'flexure'), 'piezo': ('modes', 'real_pole')}


def _read_yaml(path: Path):
    try:
        return yaml.load(path.read_text(), Loader=_Loader)
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f'{path}: cannot read: {_one_line(exc)}') from None


def _merge_belief(raw: dict, machine: MachineConfig, path: Path) -> None:
    """Merge the belief file `path` (``machine-ctrl identify --out``'s fragment) into the
    machine's `raw` mapping (of `machine`, already checked alone): per axis, a rigid-body
    drive's mass and damping, and the numbers of the axis's own law's section and of its
    lugre_feedforward; a flexure stage's mass, damping and flexure; a piezo drive's model
    (modes, real_pole). Anything else is refused: the
    plant above all (the truth hw_sim simulates), another law, a control section the axis does
    not have."""
    belief = _read_yaml(path)
    top = _Section({} if belief is None else belief, path, '')
    axes = top.section('axes')
    top.finish()
    for name in map(str, axes.data):
        if name not in machine.axis_names:
            axes.fail(f'unknown axis (the machine has {", ".join(machine.axis_names)})', name)
        section, axis = axes.section(name), machine.axis(name)
        target = raw['axes'][name] = copy.deepcopy(raw['axes'][name])    # YAML anchors share mappings
        for key in map(str, section.data):
            if key == 'drive':
                drive = section.section('drive')
                allowed = BELIEF_DRIVE_KEYS.get(axis.drive.type)
                if allowed is None:
                    drive.fail(f'a {axis.drive.type} drive has no model of its own apart from its simulated plant; a '
                               f'belief file sets the drive only of {", ".join(BELIEF_DRIVE_KEYS)} drives')
                extra = sorted(set(map(str, drive.data)) - set(allowed))
                if extra:
                    drive.fail(f'{", ".join(extra)}: a belief file sets only a {axis.drive.type} drive\'s '
                               f'{" and ".join(allowed)}')
                target['drive'].update(drive.data)
            elif key == 'control':
                control = section.section('control')
                if axis.control is None:
                    control.fail('the axis has no control section to change')
                allowed = {axis.control.law} | ({'lugre_feedforward'} if axis.control.lugre_feedforward else set())
                extra = sorted(set(map(str, control.data)) - allowed)
                if extra:
                    control.fail(f'{", ".join(extra)}: a belief file sets only the numbers of the axis\'s '
                                 f'{" and ".join(sorted(allowed))}')
                for law in control.data:
                    control.section(law)
                    target['control'][law] = {**target['control'][law], **control.data[law]}
            else:
                section.fail(f'a belief file sets only {", ".join(BELIEF_KEYS)} (the plant is the truth hw_sim '
                             f'simulates)', key)


def load_machine(name_or_path: str | Path = DEFAULT_MACHINE, belief: Sequence[str | Path] = ()) -> MachineConfig:
    """Load a machine by name (``config/machines/<name>.yaml``) or by YAML path; `belief`: files
    of the controllers' values (:func:`_merge_belief`) merged over the machine's own, in order.
    The machine is checked alone first; a value of a belief file that the merged config
    refuses is reported with the belief files named."""
    path = resolve_machine(name_or_path)
    raw = _read_yaml(path)
    if not belief:
        return _build_machine(raw, path)
    machine = _build_machine(copy.deepcopy(raw), path)
    for file in belief:
        _merge_belief(raw, machine, Path(file))
    try:
        return _build_machine(raw, path)
    except ConfigError as exc:
        where = str(exc).removeprefix(f'{path}: ')
        raise ConfigError(f'{", ".join(map(str, belief))} (over {path.name}): {where}') from None


def _build_machine(raw, path: Path) -> MachineConfig:
    """The machine of the YAML mapping `raw` read from `path`."""
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

    for axis in axes:
        problem = _drive_problem(axis.drive)
        if problem:
            axes_section.fail(problem, f'{axis.name}.drive')
        problem = _plant_problem(axis, control_period)
        if problem:
            axes_section.fail(problem, f'{axis.name}.plant')
    home = tuple(0.0 for _ in axes)
    if 'home' in top.data:
        home_section = top.section('home')
        home = tuple(home_section.number(a.name, 0.0) for a in axes)
        home_section.finish()
    dual_stage = _dual_stage(top, axes) if 'dual_stage' in top.data else ()
    cartesian = _cartesian_dual_stage(top.section('cartesian_dual_stage'), axes, dual_stage, control_period) \
        if 'cartesian_dual_stage' in top.data else None
    simulation = _read(top.section('simulation'), SimulationConfig) if 'simulation' in top.data \
        else SimulationConfig()
    problem = simulation.tool_compliance and _compliance_problem(simulation.tool_compliance, control_period)
    if problem:
        top.section('simulation').fail(problem, 'tool_compliance')
    contour = _contour_control(top.section('contour_control'), axes) if 'contour_control' in top.data else None
    top._used.update(('dual_stage', 'simulation', 'cartesian_dual_stage', 'contour_control'))
    top.finish()
    for axis, value in zip(axes, home):
        if not axis.in_stroke(value):
            raise ConfigError(f'{path}: home.{axis.name}: {value:g} is outside the stroke {axis.stroke}')
    return MachineConfig(name, description, path, urdf_path, control_period, workpiece_frame,
                         tool_frame, tuple(axes), home, dual_stage, simulation, cartesian, contour)


# assumed: semi-implicit Euler at the control period resolves the mode when w T <= 0.05 (a
# relative frequency error below 1e-3, hw_sim/tool_deflection.py)
COMPLIANCE_STEP_LIMIT = 0.05


def _compliance_problem(c: ToolComplianceConfig, period: float) -> str:
    if 2.0 * math.pi * c.eigenfrequency * period > COMPLIANCE_STEP_LIMIT:
        return (f'eigenfrequency {c.eigenfrequency:g} Hz is too high for the control period {period:g} s '
                f'(2 pi f T must be <= {COMPLIANCE_STEP_LIMIT:g})')
    if c.stiffness_variation >= c.stiffness:
        return f'stiffness_variation {c.stiffness_variation:g} must be below the stiffness {c.stiffness:g} N/m'
    for key in ('block_x', 'block_y'):
        lo, hi = getattr(c.milling, key)
        if not lo < hi:
            return f'milling.{key}: [{lo:g}, {hi:g}] is empty (low must be below high)'
    return ''


FLEXURE_ONLY = ('flexure', 'current_loop', 'sensor_bandwidth', 'sensor_noise_density', 'current_noise', 'accelerometer',
                'ground_vibration')


def _drive_problem(drive: DriveConfig) -> str:
    """Why the drive section is incomplete for its type, or ''."""
    closed = drive.type in CLOSED_LOOP_DRIVES
    if closed and (drive.mass is not None or drive.damping is not None):
        return f'a {drive.type} drive has no mass or damping of its own (its plant is its closed loop)'
    if closed and (drive.force_constant != 1.0 or drive.amplifier_gain != 1.0):
        return f'a {drive.type} drive has no force_constant or amplifier_gain (its command is a position)'
    if not closed and (drive.mass is None or drive.damping is None):
        return f'a {drive.type} drive needs mass and damping'
    if drive.type != 'piezo' and (drive.modes or drive.real_pole):
        return 'modes and real_pole: only for piezo drives (the controllers\' model of the stage)'
    if drive.type != 'voice_coil' and drive.flexure is not None:
        return 'flexure: only for voice_coil drives (the controllers\' model of the stage)'
    if drive.type == 'piezo' and not drive.modes:
        return ('a piezo drive needs modes (at least one: omega, zeta): the controllers\' model of the stage, '
                'plant.modes being the truth')
    return _modes_problem(drive.modes)


def _modes_problem(modes) -> str:
    overdamped = [f'{m.omega:g} rad/s' for m in modes if m.zeta >= 1.0]
    if overdamped:
        return (f'modes: zeta must be below 1 (a lightly damped pole pair; an overdamped one is two real poles): '
                f'{", ".join(overdamped)}')
    return ''


def _plant_problem(axis: AxisConfig, period: float) -> str:
    """Why the plant section cannot be simulated with this drive and period, or ''."""
    plant, drive = axis.plant, axis.drive
    closed = drive.type in CLOSED_LOOP_DRIVES
    if plant is None:
        return ''
    own_body = [k for k in ('mass', 'damping') if getattr(plant, k) is not None]
    if own_body and drive.type not in TRUE_BODY_DRIVES:
        return (f'{", ".join(own_body)}: a true body apart from the drive\'s is only for '
                f'{", ".join(TRUE_BODY_DRIVES)} drives')
    if drive.type in TRUE_BODY_DRIVES and len(own_body) < 2:
        return (f'a {drive.type} drive\'s plant needs mass and damping: the truth hw_sim simulates (the drive\'s '
                f'are the controllers\' belief; the same numbers where they agree)')
    own = {'position_servo': ('servo',), 'piezo': ('modes', 'real_pole')}
    for kind, keys in own.items():
        used = [k for k in keys if getattr(plant, k)]
        if drive.type != kind and used:
            return f'{", ".join(used)}: only for {kind} drives'
    if closed:
        others = [k for k in ('friction', 'resonance', 'antiresonance', 'force_noise', 'loop_delay') + FLEXURE_ONLY
                  if getattr(plant, k)]
        if others:
            return f'{", ".join(others)}: not modelled for a {drive.type} drive (its plant is its closed loop)'
        if drive.type == 'position_servo' and plant.servo is None:
            return 'a position_servo drive needs servo (its closed loop: omega, zeta)'
        if drive.type == 'piezo' and not plant.modes:
            return 'a piezo drive needs modes (at least one: omega, zeta)'
        return _modes_problem(plant.modes)
    if drive.type == 'voice_coil':
        missing = [k for k in ('flexure', 'current_loop') if getattr(plant, k) is None]
        if missing:
            return f'a voice_coil drive needs {" and ".join(missing)}'
        if plant.friction or plant.resonance or plant.force_noise:
            return 'friction, resonance and force_noise are not modelled for a voice_coil drive'
        white = plant.sensor_noise_density
        if white is not None and (white.corner or white.peak is not None or white.rolloff):
            return 'sensor_noise_density: only white sensor noise is modelled (density; no corner, no peak, no rolloff)'
        if plant.ground_vibration is not None and not plant.ground_vibration.rolloff:
            return ('ground_vibration needs a rolloff (rad/s): the root\'s velocity drives the flexure\'s damper, '
                    'and a displacement flat to infinite frequency has none')
        if plant.loop_delay >= period:
            return f'loop_delay {plant.loop_delay:g} s must be shorter than the control period {period:g} s'
        return ''
    extra = [k for k in FLEXURE_ONLY if getattr(plant, k) is not None]
    if extra or plant.loop_delay:
        return f'{", ".join(extra or ["loop_delay"])}: only for voice_coil drives'
    return ''


def _dual_stage(top: _Section, axes: list[AxisConfig]) -> tuple[DualStagePair, ...]:
    raw = top._get('dual_stage', _REQUIRED)
    if not isinstance(raw, list):
        top.fail('must be a list of {coarse, fine, sign}', 'dual_stage')
    by_name = {a.name: a for a in axes}
    pairs = []
    for i, item in enumerate(raw):
        s = _Section(item, top.file, f'dual_stage[{i}]')
        pair = DualStagePair(s.string('coarse'), s.string('fine'), s.number('sign'))
        s.finish()
        for role in ('coarse', 'fine'):
            axis = by_name.get(getattr(pair, role))
            if axis is None:
                s.fail(f'unknown axis {getattr(pair, role)!r}', role)
        if pair.sign not in (1.0, -1.0):
            s.fail(f'must be 1 or -1, got {pair.sign:g}', 'sign')
        if by_name[pair.coarse].kind != by_name[pair.fine].kind:
            s.fail('coarse and fine axes must be of the same kind')
        pairs.append(pair)
    fines = [p.fine for p in pairs]
    if len(set(fines)) != len(fines):
        top.fail('a fine axis appears in two pairs', 'dual_stage')
    return tuple(pairs)


def _cartesian_dual_stage(s: _Section, axes: list[AxisConfig], pairs, control_period: float) -> CartesianCoupling:
    by_name = {a.name: a for a in axes}
    roles = {}
    for role in ('coarse', 'fine'):
        raw = s._get(role, _REQUIRED)
        if not (isinstance(raw, list) and raw and all(isinstance(n, str) for n in raw)):
            s.fail('must be a non-empty list of axis names', role)
        unknown = [n for n in raw if n not in by_name]
        if unknown:
            s.fail(f'unknown axis {", ".join(map(repr, unknown))}', role)
        if len(set(raw)) != len(raw):
            s.fail('names an axis twice', role)
        roles[role] = tuple(raw)
    tracker = _read(s.section('tracker'), TrackerConfig) if 'tracker' in s.data else None
    midranging = _read(s.section('midranging'), MidRangingConfig) if 'midranging' in s.data else None
    s.finish()
    if midranging is not None and not midranging.time_constant > control_period:
        s.section('midranging').fail(f'{midranging.time_constant:g} s must be above the control period '
                                     f'{control_period:g} s (the take-over h/T per step below 1: from 1 it rings, '
                                     f'from 2 it diverges)', 'time_constant')
    if set(roles['coarse']) & set(roles['fine']):
        s.fail('an axis cannot be both coarse and fine')
    paired = {name for p in pairs for name in (p.coarse, p.fine)}
    if paired & set(roles['coarse'] + roles['fine']):
        s.fail(f'{", ".join(sorted(paired & set(roles["coarse"] + roles["fine"])))}: already in a dual_stage pair')
    if not 1 <= len(roles['fine']) <= 3:
        s.fail(f'{len(roles["fine"])} fine axes: the tool-tip position has three coordinates', 'fine')
    if any(by_name[n].kind != 'linear' or by_name[n].stroke is None for n in roles['fine']):
        s.fail('fine axes must be linear with a stroke', 'fine')
    return CartesianCoupling(roles['coarse'], roles['fine'], tracker, midranging)


def _contour_control(s: _Section, axes: list[AxisConfig]) -> ContourControlConfig:
    by_name = {a.name: a for a in axes}
    raw = s._get('axes', _REQUIRED)
    if not (isinstance(raw, list) and raw and all(isinstance(n, str) for n in raw)):
        s.fail('must be a non-empty list of axis names', 'axes')
    unknown = [n for n in raw if n not in by_name]
    if unknown:
        s.fail(f'unknown axis {", ".join(map(repr, unknown))}', 'axes')
    if len(set(raw)) != len(raw):
        s.fail('names an axis twice', 'axes')
    uncontrolled = [n for n in raw if by_name[n].control is None]
    if uncontrolled:
        s.fail(f'{", ".join(uncontrolled)}: no control section (the correction moves a servo\'s reference)', 'axes')
    linear = [n for n in raw if by_name[n].kind == 'linear']
    rotary = [n for n in raw if by_name[n].kind == 'rotary']
    if not linear:
        s.fail('the tool-tip channel needs at least one linear axis', 'axes')
    hints = typing.get_type_hints(ContourControlConfig)
    values = {f.name: _value(s, f, hints[f.name]) for f in fields(ContourControlConfig)
              if f.name != 'axes' and (f.name in s.data or f.default is MISSING)}
    s.finish()
    if values.get('orientation') is not None and not rotary:
        s.fail('the orientation channel needs a rotary axis among axes', 'orientation')
    if values.get('orientation') is None and rotary:
        s.fail(f'{", ".join(rotary)}: a rotary axis takes the orientation correction, and there is no orientation '
               f'channel', 'axes')
    return ContourControlConfig(tuple(raw), **values)


def config_dirs() -> list[Path]:
    """Where machine descriptions are looked up, first match wins: the source checkout this
    package runs from (editable install), the ament index, then the Python prefix."""
    dirs = []
    source = Path(__file__).resolve().parents[2]
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
