"""The Python a lock-step step costs in each node, without the transport: hw_sim,
servo_coarse, servo_fine and dual_stage of the default micromill graph made in this
process (rclpy initialised, nothing spun), their publishers captured and their
subscriptions' callbacks called in the graph's order with the bytes the others published
(state -> dual_stage, servo_coarse, servo_fine; offsets -> servo_fine; commands -> hw_sim;
a held 500-row reference chunk whenever the stream is less than 3000 rows ahead, as the
idle trajectory node sends). Per node the process time of its callbacks per step
(reference chunks apart, as ref_<node>); median and min of the repeats.

    .venv/bin/python bench/step_cost.py [--steps 3000] [--repeats 5] [--profile]

Why: bench/graph_cpu.py gives a node process's whole CPU per step, rclpy and Fast DDS
included, on a shared machine; this isolates what the nodes' own code costs, which is what
a change to it moves. Process time is noisy on a loaded VM (a whole run is sometimes 1.3x
slower): compare trees in alternating runs (PYTHONPATH=<tree>) and look at the minima.
After 500 steps of warm-up the heap is frozen (gc.freeze), as node_common.spin does.
Not used by the test suite.
"""
from __future__ import annotations

import argparse
import collections
import gc
import os
import statistics
import sys
import time

NODES = ('hw_sim', 'servo_coarse', 'servo_fine', 'dual_stage')
CHUNK = 500
AHEAD = 3000


class Graph:
    """The four nodes in this process, their publishers captured by topic."""

    def __init__(self, machine_name: str = 'micromill_9axis'):
        import numpy as np
        from rclpy.publisher import Publisher

        from machine_ctrl.model.config import load_machine
        from machine_ctrl.ros import messages as ros_io
        from machine_ctrl.ros.graph import default_graph

        self.sent: dict[str, list] = collections.defaultdict(list)
        names = {}

        def capture(publisher, msg) -> None:
            topic = names.get(id(publisher))
            if topic is None:
                topic = names[id(publisher)] = publisher.topic_name
            self.sent[topic].append(msg)
        Publisher.publish = capture                  # before the nodes bind publish anywhere
        self.machine = load_machine(machine_name)
        specs = {s.name: s for s in default_graph(self.machine, contour=None)}
        self.nodes = {n: specs[n].create() for n in NODES}
        clock = ros_io.StepClock.of(self.machine)
        home = np.tile(np.asarray(self.machine.home, float), (CHUNK, 1))
        self.chunk = lambda first: ros_io.trajectory_chunk(clock, first, self.machine.axis_names, home,
                                                          np.zeros_like(home), np.zeros_like(home))
        self.state = {n: self.callback(n, '/joint_states') for n in NODES[1:]}
        self.reference = {n: self.callback(n, '/reference') for n in NODES[1:]}
        self.offsets = self.callback('servo_fine', '/dual_stage/offsets')
        self.command = self.callback('hw_sim', '/servo_commands')
        self.streamed = 0                            # first step not yet streamed

    def callback(self, node: str, topic: str):
        (callback,) = [s.callback for s in self.nodes[node].subscriptions if s.topic_name == topic]
        return callback

    def run(self, steps: int) -> dict[str, float]:
        """Process s of each node's callbacks over `steps` steps."""
        spent = collections.defaultdict(float)
        clock = time.process_time
        hw_sim = self.nodes['hw_sim'].session
        for _ in range(steps):
            step = hw_sim.step
            while self.streamed < step + AHEAD:
                data = self.chunk(self.streamed)
                for name, take in self.reference.items():
                    t = clock()
                    take(data)
                    spent['ref_' + name] += clock() - t
                self.streamed += CHUNK
            state = self.sent.pop('/joint_states')[-1]
            self.sent.clear()
            t = clock()
            self.state['dual_stage'](state)
            spent['dual_stage'] += clock() - t
            t = clock()
            self.state['servo_coarse'](state)
            spent['servo_coarse'] += clock() - t
            offsets = self.sent.pop('/dual_stage/offsets')[-1]
            t = clock()
            self.state['servo_fine'](state)
            self.offsets(offsets)
            spent['servo_fine'] += clock() - t
            commands = self.sent.pop('/servo_commands')
            t = clock()
            for command in commands:
                self.command(command)
            spent['hw_sim'] += clock() - t
            if hw_sim.step != step + 1:
                raise RuntimeError(f'hw_sim did not advance from step {step}: {hw_sim.status(0.0).values}')
        return spent


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--steps', type=int, default=3000)
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--profile', action='store_true', help='cProfile one run of --steps (process time)')
    args = parser.parse_args(argv)
    import rclpy

    from machine_ctrl.app.processes import isolated_ros_env, reserve_ros_domain
    with reserve_ros_domain() as lease:
        os.environ.update(isolated_ros_env(lease.domain_id))
        rclpy.init()
        graph = None
        try:
            graph = Graph()
            graph.run(500)
            gc.collect()
            gc.freeze()
            if args.profile:
                import cProfile
                import pstats
                profile = cProfile.Profile(time.process_time)
                profile.runcall(graph.run, args.steps)
                pstats.Stats(profile).sort_stats('tottime').print_stats(40)
                return
            runs = collections.defaultdict(list)
            for _ in range(args.repeats):
                for name, seconds in graph.run(args.steps).items():
                    runs[name].append(seconds / args.steps * 1e6)
            print(f'{graph.machine.name}, {args.repeats} x {args.steps} steps, process time of the callbacks, '
                  f'us per step (median, min); modules from {os.path.dirname(sys.modules["machine_ctrl"].__path__[0])}')
            for name, values in sorted(runs.items()):
                print(f'{name:18s}{statistics.median(values):9.2f}{min(values):9.2f}')
        finally:
            for node in graph.nodes.values() if graph else ():
                node.destroy_node()
            rclpy.try_shutdown()


if __name__ == '__main__':
    os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    main()
