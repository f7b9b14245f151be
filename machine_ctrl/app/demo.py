"""``machine-ctrl demo``: the main job, end to end on the default 9-axis micromill.

1. a simulated laser measurement campaign and its fit (thesis Ch. 5; compensation/) give
   the geometric error model: OUT/measurement.csv, OUT/model.yaml;
2. bringup (machine_ctrl.app.bringup) of the whole graph, each node its own process, in a ROS
   domain of its own, recording into OUT/bag, dual stage on, compensation on with that model,
   until hw_sim says the graph is ready (contract.READY);
3. the CIRP helix (seed 002 §5; trajectory.toolpath.helix, shortened to ``turns`` so the
   demo takes a few minutes here) sent as a nav_msgs/Path, as another robot would, followed
   by its goal id (machine_ctrl.app.goals) with the progress shown until it has succeeded;
4. everything stopped (the bag closed, counts printed), then machine_ctrl.recording.analysis on the
   bag: the table (tracking, dual-stage, tool-tip tracking and contour errors, drive-limit
   and fine-stroke usage) and the PNG plots in OUT, next to the bag.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from machine_ctrl import contract

DEFAULT_TURNS = 1.0     # of the 5 mm-radius helix: ~3.2 s of machine time at 10 mm/s


def fit_model(machine, out: Path) -> tuple[Path, float]:
    """Campaign on the simulated machine (its true map) -> OUT/measurement.csv -> fitted
    quintics -> OUT/model.yaml; returns the model path and the largest fit residual (m)."""
    from compensation.error_map import load_error_map
    from compensation.error_model import ErrorKinematics
    from compensation.fitting import measure_and_fit
    true_map = load_error_map(machine.simulation.error_map_path(machine.yaml_path), machine.axis_names)
    truth = ErrorKinematics.from_config(machine, true_map)
    _, model_path, _, residuals = measure_and_fit(truth, true_map, machine.simulation.seed, out,
                                                  f'{machine.name}, machine-ctrl demo')
    return model_path, max(r.max for r in residuals if r.error.startswith('d'))


def output_directory(out: str | None) -> Path:
    """OUT (created; its bag/ must not exist yet) or a new temporary directory."""
    path = Path(out) if out else Path(tempfile.mkdtemp(prefix='machine_ctrl_demo_'))
    if (path / 'bag').exists():
        raise ValueError(f'{path / "bag"}: exists; give a new --out directory')
    path.mkdir(parents=True, exist_ok=True)
    return path


class Clock:
    """Wall-clock phases for the closing summary."""

    def __init__(self):
        self.start = self.mark = time.monotonic()
        self.phases: list[tuple[str, float]] = []

    def lap(self, label: str) -> None:
        now = time.monotonic()
        self.phases.append((label, now - self.mark))
        self.mark = now

    def summary(self) -> str:
        return ', '.join(f'{label} {seconds:.1f} s' for label, seconds in self.phases) + \
            f'; total {time.monotonic() - self.start:.1f} s'


def run(args) -> int:
    from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine
    from trajectory import toolpath
    if not (0 < args.turns <= 3):
        print(f'machine-ctrl: demo: --turns must be in (0, 3], got {args.turns}', file=sys.stderr)
        return 2
    try:
        out = output_directory(args.out)
    except (ValueError, OSError) as exc:
        print(f'machine-ctrl: demo: {exc}', file=sys.stderr)
        return 2
    clock = Clock()
    machine = load_machine(DEFAULT_MACHINE)
    print(f'machine-ctrl demo: {machine.name}, output in {out}', flush=True)
    model, residual = fit_model(machine, out)
    print(f'geometric error model fitted from the simulated campaign: {model} '
          f'(largest fit residual {residual * 1e6:.3f} um)', flush=True)
    clock.lap('measurement and fit')
    path = toolpath.helix(turns=args.turns)
    status = run_graph(machine, path, out, model, clock)
    return status if status != 0 else analyse(machine, out, clock)


def run_graph(machine, path, out: Path, model: Path, clock: Clock) -> int:
    """Bring up, send the path, follow it, stop; the exit status."""
    from machine_ctrl.app.bringup import Bringup, Stopped, monitor, signals_ignored
    from machine_ctrl.app.client import Timeout
    from machine_ctrl.app.goals import follow_goal
    from machine_ctrl.app.processes import ChildExited, isolated_ros_env, reserve_ros_domain
    with reserve_ros_domain() as lease:
        env = isolated_ros_env(lease.domain_id)
        with monitor(machine, 'demo_client', lease.domain_id) as client:
            with Bringup(machine, record=str(out / 'bag'), compensation=str(model), env=env,
                         log_dir=str(out / 'logs')) as bringup:
                try:
                    bringup.start()
                    print(f'bringing up {len(bringup.specs)} nodes + recorder (ROS domain {lease.domain_id}, '
                          f'logs in {bringup.log_dir}) ...', flush=True)
                    waited = bringup.wait_ready(client)
                    print(f'all nodes ready after {waited:.1f} s', flush=True)
                    clock.lap('bringup')
                    print(f'sending the helix ({len(path)} points) on {contract.PATH.name}', flush=True)
                    client.wait_listening(30)
                    status = follow_goal(client, lambda stamp: client.send_path(path, stamp=stamp), 3600.0)
                    clock.lap('motion')
                except (ChildExited, Timeout) as exc:
                    print(f'machine-ctrl: demo: {exc}', file=sys.stderr)
                    return 1
                except Stopped:
                    print('interrupted: stopping', file=sys.stderr)
                    return 130
                finally:
                    with signals_ignored():
                        print('stopping the graph and closing the bag ...', flush=True)
                        for line in bringup.stop():
                            print(line, flush=True)
                    clock.lap('shutdown')
    return status


def analyse(machine, out: Path, clock: Clock) -> int:
    from machine_ctrl.recording import analysis
    from machine_ctrl.recording import plots
    try:
        result = analysis.analyse(analysis.load(out / 'bag', machine))
    except ValueError as exc:
        print(f'machine-ctrl: demo: {exc}', file=sys.stderr)
        return 1
    print(analysis.table([result], [machine]))
    written = plots.write([result], machine, out)
    print(f'plots: {", ".join(str(p) for p in written)}')
    clock.lap('analysis')
    machine_time = result['duration']
    wall = time.monotonic() - clock.start
    print(f'wall time: {clock.summary()}')
    print(f'{machine_time:.2f} s of machine time ({result["steps"]} steps) in {wall:.0f} s wall: '
          f'real-time factor {machine_time / wall:.4f} over the whole demo')
    return 0
