"""Bag analysis (no rclpy): what a recorded session did, from the bag alone.

Input: /joint_states (measured axis positions, stamp = step k * T) and /reference (chunks
on the control grid: header.stamp = t of the first row, row i at step first + i; a later
chunk replaces what earlier ones said from its first step on, as the servos' buffer does).
/joint_states is decoded by machine_ctrl.recording.cdr, /reference and the ground truth with
the bag's own ``ros2msg`` schemas (mcap-ros2-support), so no ROS installation is needed. A /joint_states stamp seen twice (hw_sim re-sends a state while it
waits) counts once. The machine is the one named in the bag's custom_data (recorded by
``machine-ctrl record --machine`` and ``experiment --record``) unless given.

Results (SI: m, rad, s; the text table prints um / urad):

* ``session``: how the graph ran, as its recorder kept it (the bag's session facts,
  machine_ctrl.recording.recorder.session_of: hw_sim's mode, real-time factor, belief
  files); {} for a bag without.
* ``tracking``: per axis, reference - measured: mean |e|, max |e|, RMS.
* ``dual_stage``: per dual-stage pair, the error of the pair's combined position
  (coarse + sign * fine), which is what the workpiece sees.
* ``tool_tip``: forward kinematics of the reference and the measured positions
  (:class:`machine_ctrl.model.kinematics.Kinematics`): ``tracking`` = |P_ref(k) - P_meas(k)|,
  ``contour`` = distance of P_meas(k) from the reference tool path (the polyline of P_ref,
  searched within ``CONTOUR_WINDOW`` s of step k).
  With the simulated machine's ground truth in the bag (/hw_sim/ground_truth/tool_pose, every
  few steps), ``true_tracking`` = |P_ref(k) - P_true(k)| at those steps: the error the
  encoders cannot see (a structure deflected by the cutting force, a geometric error map).
* ``limits``: per axis peak |v|, |a|, |j| over the axis limits, of the reference (finite
  differences at the control period) and of the measured positions (finite differences over
  ``DIFF_STEPS`` periods).
* ``fine_stroke``: per fine-stage axis, min and max position and the peak fraction of the
  half stroke used about its centre.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from mcap_ros2._dynamic import generate_dynamic

from machine_ctrl import contract
from machine_ctrl.recording.bag import Bag, BagError
from machine_ctrl.recording.cdr import JointStateDecoder
from machine_ctrl.model.config import MachineConfig, load_machine
from machine_ctrl.model.errors import ConfigError, InvalidMessage
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.recording.recorder import MACHINE_FILE_KEY, MACHINE_KEY, namespace_of, session_of

REQUIRED = (contract.JOINT_STATES, contract.REFERENCE)
# assumed: the tool tip lags its reference by far less than 50 ms at the feeds we run
# (10 mm/s: 0.5 mm of path), so the nearest reference point lies within this window.
CONTOUR_WINDOW = 0.05      # s
# assumed: points per block of contour_errors: 64 rows keep its (rows, 2 window) temporaries
# in the cache (bench/contour_analysis.py measures the whole search, not the block size)
CONTOUR_BLOCK = 64
# assumed: 10 periods (1 ms on the micromill) resolve the drives' bandwidth (< 400 Hz) and
# divide the encoder quantization in the differenced |a| and |j| by 10^2 and 10^3.
DIFF_STEPS = 10


class AnalysisError(ValueError):
    """A bag that cannot be analysed; one line."""


@dataclass
class Run:
    """Aligned per-step data of a bag: rows are the steps present in both streams."""
    machine: MachineConfig
    steps: np.ndarray           # control step numbers
    measured: np.ndarray        # (n, axes)
    reference: np.ndarray       # (n, axes)
    source: str
    session: dict = field(default_factory=dict)     # how the graph ran (recorder.session_of), {} when unsaid
    true_tip: dict[int, tuple[float, float, float]] = field(default_factory=dict)   # step -> true tool tip


def _decoder(bag: Bag, topic: str):
    schema = next(s for s in bag.summary.schemas.values() if s.name == bag.topics[topic].type)
    return generate_dynamic(schema.name, schema.data.decode())[schema.name]


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * contract.NS_PER_SECOND + int(header.stamp.nanosec)


def machine_of(bag: Bag, machine: str | MachineConfig | None) -> MachineConfig:
    if isinstance(machine, MachineConfig):
        return machine
    data = bag.custom_data
    names = [machine] if machine else [data.get(MACHINE_KEY), data.get(MACHINE_FILE_KEY)]
    names = [n for n in names if n]
    if not names:
        raise AnalysisError(f'{bag.path}: the bag does not name its machine; give --machine')
    problem = None
    for name in names:
        try:
            return load_machine(name)
        except ConfigError as exc:
            problem = exc
    raise AnalysisError(f'{bag.path}: machine {names[0]!r}: {problem}')


def load(path, machine: str | MachineConfig | None = None) -> Run:
    """Decode and align a bag; AnalysisError / BagError (one line) when it cannot be used."""
    with Bag(path) as bag:
        namespace, session = namespace_of(bag.custom_data), session_of(bag.custom_data)
        states_topic, reference_topic = (topic.full(namespace) for topic in REQUIRED)
        for topic in REQUIRED:
            info = bag.topics.get(topic.full(namespace))
            if info is None or info.count == 0:
                raise AnalysisError(f'{bag.path}: no {topic.full(namespace)} messages in the bag; analysis needs '
                                    f'{states_topic} and {reference_topic}')
            if info.type != topic.type:
                raise AnalysisError(f'{bag.path}: {topic.full(namespace)} is {info.type}, expected {topic.type}')
        config = machine_of(bag, machine)
        period_ns = contract.StepClock.of(config).period_ns
        names = list(config.axis_names)
        add_state, states = _states(states_topic, period_ns, names)
        add_chunk, reference = _reference(bag, reference_topic, period_ns, names)
        readers = {states_topic: add_state, reference_topic: add_chunk}
        truth_topic = contract.TRUE_TOOL_POSE.full(namespace)
        info = bag.topics.get(truth_topic)
        true_tip = {}
        if info is not None and info.type == contract.TRUE_TOOL_POSE.type:
            readers[truth_topic], true_tip = _true_tips(bag, truth_topic, period_ns)
        for message in bag.messages(list(readers)):          # one pass over the bag's chunks
            readers[message.topic](message.data)
    steps = np.array(sorted(set(states) & set(reference)), dtype=np.int64)
    if len(steps) == 0:
        raise AnalysisError(f'{path}: no control step has both a {states_topic} and a {reference_topic} row')
    return Run(config, steps, np.array([states[k] for k in steps]), np.array([reference[k] for k in steps]),
               str(path), session, true_tip)


def _columns(message_names, wanted, topic) -> list[int]:
    index = {n: i for i, n in enumerate(message_names)}
    missing = [w for w in wanted if w not in index]
    if missing:
        raise AnalysisError(f'{topic}: no joint {", ".join(missing)} (not this machine?)')
    return [index[w] for w in wanted]


def _states(topic: str, period_ns: int, names):
    """(add, rows): add(data) takes one state message's bytes (decoded by recording.cdr) into
    rows, step -> positions of `names`; a stamp seen before or off the grid is left out."""
    decoder = JointStateDecoder()
    rows: dict[int, list[float]] = {}
    picks = None

    def add(data: bytes) -> None:
        nonlocal picks
        try:
            msg = decoder.decode(data)
        except InvalidMessage as exc:
            raise AnalysisError(f'{topic}: {exc}') from None
        step, rest = divmod(msg.sec * contract.NS_PER_SECOND + msg.nanosec, period_ns)
        if rest or step in rows:
            return
        if picks is None or len(msg.name) != len(names):
            picks = _columns(list(msg.name), names, topic)
        rows[step] = [msg.position[i] for i in picks]
    return add, rows


def _reference(bag: Bag, topic: str, period_ns: int, names):
    """(add, rows): add(data) takes one reference chunk into rows, step -> positions of
    `names` (a later chunk replaces from its first step on)."""
    decode = _decoder(bag, topic)
    rows: dict[int, list[float]] = {}
    end = 0

    def add(data: bytes) -> None:
        nonlocal end
        msg = decode(data)
        first, rest = divmod(_stamp_ns(msg.header), period_ns)
        if rest or not msg.points:
            return
        picks = _columns(list(msg.joint_names), names, topic)
        for k in range(first, end):            # a new chunk replaces from its first step on
            rows.pop(k, None)
        for i, point in enumerate(msg.points):
            rows[first + i] = [point.positions[c] for c in picks]
        end = max(end, first + len(msg.points))
    return add, rows


def _true_tips(bag: Bag, topic: str, period_ns: int):
    """(add, tips): add(data) takes one ground-truth tool pose into tips, step -> (x, y, z)."""
    decode = _decoder(bag, topic)
    tips: dict[int, tuple[float, float, float]] = {}

    def add(data: bytes) -> None:
        msg = decode(data)
        step, rest = divmod(_stamp_ns(msg.header), period_ns)
        if not rest:
            p = msg.pose.position
            tips[step] = (p.x, p.y, p.z)
    return add, tips


def error_stats(errors: np.ndarray) -> dict[str, float]:
    """mean |e|, max |e|, RMS of a 1-D error series."""
    a = np.abs(errors)
    return {'mean': float(a.mean()), 'max': float(a.max()), 'rms': float(math.sqrt(np.mean(errors * errors)))}


def tool_tips(kinematics: Kinematics, q: np.ndarray) -> np.ndarray:
    return np.array([kinematics.forward(row)[0] for row in q])


def contour_errors(path: np.ndarray, points: np.ndarray, window: int) -> np.ndarray:
    """Distance of each point i from the polyline `path`: the nearest path vertex within
    i +- window, then the nearer of the (up to two) segments meeting there. Row i of both is
    step i: ValueError for arrays of different lengths (a point without a vertex in its
    window would have no answer)."""
    if len(path) != len(points):
        raise ValueError(f'path and points must have one row per step each, got {len(path)} and {len(points)}')
    n, last = len(points), len(path) - 1
    result = np.empty(n)
    for start in range(0, n, CONTOUR_BLOCK):
        stop = min(start + CONTOUR_BLOCK, n)
        lo, hi = max(start - window, 0), min(stop + window, last + 1)
        block = points[start:stop]
        # squared distances summed per coordinate in place (x, then + y, then + z: the order
        # and so the bits of a sum over the coordinate axis, without its (rows, columns, 3) temporaries)
        d2 = np.subtract.outer(block[:, 0], path[lo:hi, 0])
        d2 *= d2
        for c in range(1, path.shape[1]):
            d = np.subtract.outer(block[:, c], path[lo:hi, c])
            d *= d
            d2 += d
        index = np.arange(start, stop)[:, None]
        # a vertex outside a point's own window can only lie among the first or last
        # (stop - start) columns (the band's corners): masked there only
        m = stop - start
        for cols in (slice(0, min(m, hi - lo)), slice(max(hi - lo - m, 0), hi - lo)):
            corner = d2[:, cols]
            corner[np.abs(np.arange(lo, hi)[cols][None, :] - index) > window] = np.inf
        nearest = lo + np.argmin(d2, axis=1)
        best = np.sqrt(d2[np.arange(stop - start), nearest - lo])
        for j in (np.maximum(nearest - 1, 0), np.minimum(nearest, max(last - 1, 0))):
            if last < 1:
                break
            p0, d = path[j], path[j + 1] - path[j]
            length2 = np.einsum('ij,ij->i', d, d)
            u = np.einsum('ij,ij->i', block - p0, d) / np.where(length2 > 0, length2, 1.0)
            foot = p0 + np.clip(u, 0.0, 1.0)[:, None] * d
            best = np.minimum(best, np.linalg.norm(block - foot, axis=1))
        result[start:stop] = best
    return result


def peak_ratios(q: np.ndarray, h: float, limits) -> dict[str, float]:
    """Peak |v|, |a|, |j| by finite differences of q at spacing h, over the limits."""
    out = {}
    for order, (key, limit) in enumerate(zip(('velocity', 'acceleration', 'jerk'), limits), start=1):
        d = np.diff(q, n=order) / h**order if len(q) > order else np.zeros(1)
        out[key] = float(np.abs(d).max() / limit)
    return out


def analyse(run: Run) -> dict:
    """The statistics of a run (see the module docstring)."""
    machine = run.machine
    names = list(machine.axis_names)
    contiguous = bool(np.all(np.diff(run.steps) == 1))
    result = {'source': run.source, 'machine': machine.name, 'steps': int(len(run.steps)),
              'first_step': int(run.steps[0]), 'last_step': int(run.steps[-1]),
              'duration': float((run.steps[-1] - run.steps[0]) * machine.control_period), 'session': dict(run.session),
              'tracking': {a: error_stats(run.reference[:, i] - run.measured[:, i]) for i, a in enumerate(names)}}
    result['dual_stage'] = {}
    for pair in machine.dual_stage:
        c, f = names.index(pair.coarse), names.index(pair.fine)
        combined_ref = run.reference[:, c] + pair.sign * run.reference[:, f]
        combined = run.measured[:, c] + pair.sign * run.measured[:, f]
        result['dual_stage'][f'{pair.coarse}+{pair.fine}'] = error_stats(combined_ref - combined)
    kinematics = Kinematics.from_config(machine)
    p_ref, p_meas = tool_tips(kinematics, run.reference), tool_tips(kinematics, run.measured)
    window = max(1, int(round(CONTOUR_WINDOW / machine.control_period)))
    contour = contour_errors(p_ref, p_meas, window)
    result['tool_tip'] = {'tracking': error_stats(np.linalg.norm(p_ref - p_meas, axis=1)),
                          'contour': error_stats(contour)}
    rows = [i for i, k in enumerate(run.steps.tolist()) if k in run.true_tip]
    if rows:
        p_true = np.array([run.true_tip[int(run.steps[i])] for i in rows])
        result['tool_tip']['true_tracking'] = error_stats(np.linalg.norm(p_ref[rows] - p_true, axis=1))
    result['limits'] = {'reference': {}, 'measured': {}}
    if not contiguous:
        result['limits_note'] = 'steps missing from the run: differences span the gaps'
    for i, axis in enumerate(machine.axes):
        lim = (axis.limits.velocity, axis.limits.acceleration, axis.limits.jerk)
        T = machine.control_period
        result['limits']['reference'][axis.name] = peak_ratios(run.reference[:, i], T, lim)
        result['limits']['measured'][axis.name] = peak_ratios(run.measured[::DIFF_STEPS, i], DIFF_STEPS * T, lim)
    result['fine_stroke'] = {}
    for name in machine.fine_axes:
        axis = machine.axis(name)
        q = run.measured[:, names.index(name)]
        entry = {'min': float(q.min()), 'max': float(q.max()), 'usage': None}
        if axis.stroke:
            lo, hi = axis.stroke
            entry['usage'] = float(np.abs(q - (lo + hi) / 2).max() / ((hi - lo) / 2))
        result['fine_stroke'][name] = entry
    result['series'] = {'steps': run.steps, 'errors': run.reference - run.measured,
                        'tool_ref': p_ref, 'tool_meas': p_meas,
                        'contour': contour}
    return result


def public(result: dict) -> dict:
    """The result without the per-step series (what JSON carries)."""
    return {k: v for k, v in result.items() if k != 'series'}


def _scale(machine: MachineConfig, axis_name: str) -> tuple[float, str]:
    return (1e6, 'um') if machine.axis(axis_name).kind == 'linear' else (1e6, 'urad')


def table(results: list[dict], machines: list[MachineConfig]) -> str:
    """Text table of one result, or of several side by side (ratio column for two)."""
    labels = [r['source'] for r in results]
    lines = [' | '.join(f'[{i + 1}] {label}: {r["machine"]}, {r["steps"]} steps, {r["duration"]:.4f} s'
                        for i, (label, r) in enumerate(zip(labels, results)))]
    lines += [f'[{i + 1}] session: ' + ', '.join(f'{k} {v}' for k, v in r['session'].items())
              for i, r in enumerate(results) if r['session']]
    head = f'{"":34s}' + ''.join(f'{f"[{i + 1}]":>12s}' for i in range(len(results)))
    if len(results) == 2:
        head += f'{"[1]/[2]":>10s}'
    lines.append(head)

    def row(label, values):
        text = f'{label:34s}' + ''.join(f'{v:12.4f}' for v in values)
        if len(values) == 2:
            text += f'{values[0] / values[1]:10.2f}' if values[1] else f'{"-":>10s}'
        lines.append(text)

    machine = machines[0]
    lines.append('tracking error (reference - measured)')
    for axis in results[0]['tracking']:
        scale, unit = _scale(machine, axis)
        for stat in ('mean', 'max', 'rms'):
            row(f'  {axis} {stat} |e| [{unit}]', [r['tracking'][axis][stat] * scale for r in results])
    if results[0]['dual_stage']:
        lines.append('dual-stage pairs (coarse + sign * fine)')
        for pair in results[0]['dual_stage']:
            for stat in ('mean', 'max', 'rms'):
                row(f'  {pair} {stat} [um]', [r['dual_stage'][pair][stat] * 1e6 for r in results])
    lines.append('tool tip (forward kinematics)')
    for key in ('tracking', 'contour', 'true_tracking'):
        if all(key in r['tool_tip'] for r in results):       # true_tracking: with the ground truth only
            for stat in ('mean', 'max', 'rms'):
                row(f'  {key} {stat} [um]', [r['tool_tip'][key][stat] * 1e6 for r in results])
    for source in ('reference', 'measured'):
        lines.append(f'drive-limit usage, {source} (peak |v|,|a|,|j| / limit)')
        for axis in results[0]['limits'][source]:
            for key in ('velocity', 'acceleration', 'jerk'):
                row(f'  {axis} {key}', [r['limits'][source][axis][key] for r in results])
    if results[0]['fine_stroke']:
        lines.append('fine-stage stroke usage (peak |q - centre| / half stroke)')
        for axis in results[0]['fine_stroke']:
            row(f'  {axis}', [r['fine_stroke'][axis]['usage'] or 0.0 for r in results])
    return '\n'.join(lines)


def check_comparable(a: Run, b: Run) -> None:
    if list(a.machine.axis_names) != list(b.machine.axis_names):
        raise AnalysisError(f'{a.source} ({a.machine.name}) and {b.source} ({b.machine.name}) '
                            'are runs of machines with different axes')


__all__ = ['AnalysisError', 'BagError', 'Run', 'analyse', 'load', 'public', 'table']
