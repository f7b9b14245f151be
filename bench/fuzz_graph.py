"""The long graph fuzzing campaign ([6/8] item 4): test/test_fuzz_graph.py with
MACHINE_CTRL_FUZZ_EXAMPLES topic messages (default 10,000; the test suite's slice is 300),
then its numbers: messages sent per topic, refusals counted per node, parameter sets and
service calls by outcome, node processes alive, callback errors the nodes logged, wall time.

    .venv/bin/python bench/fuzz_graph.py [--messages 10000] [--seed N] [--json FILE]

Same as `MACHINE_CTRL_FUZZ_EXAMPLES=10000 ./dev/test test/test_fuzz_graph.py`, plus the
table. Exit status: pytest's.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--messages', type=int, default=10_000, help='topic messages (default 10000)')
    parser.add_argument('--seed', help='hypothesis seed (default: derandomized, the same examples every run)')
    parser.add_argument('--json', help='also write the numbers here')
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(args.json or Path(tmp) / 'fuzz.json')
        env = {**os.environ, 'MACHINE_CTRL_FUZZ_EXAMPLES': str(args.messages), 'MACHINE_CTRL_FUZZ_REPORT': str(report)}
        env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
        if args.seed is not None:
            env['MACHINE_CTRL_FUZZ_SEED'] = args.seed
        start = time.monotonic()
        result = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', '-rxX',
                                 'test/test_fuzz_graph.py'], cwd=ROOT, env=env)
        wall = time.monotonic() - start
        if not report.exists():
            print(f'no report (pytest exit {result.returncode})', file=sys.stderr)
            return result.returncode or 1
        numbers = json.loads(report.read_text())
    print(f'\n{numbers["messages"]} topic messages in {numbers["examples"]} examples of {numbers["batch"]}, '
          f'{numbers["seconds"]:.0f} s of sending and waiting; test file {wall:.0f} s wall')
    print('\n| topic | messages |\n|---|---:|')
    for topic, n in numbers['per_topic'].items():
        print(f'| /{topic} | {n} |')
    print('\n| node counter | refusals counted |\n|---|---:|')
    for key, n in numbers['refusals'].items():
        print(f'| {key} | {n} |')
    outcomes: dict[str, int] = {}
    for key, n in numbers['parameter_sets'].items():
        outcome = key.rsplit(' ', 1)[1]
        outcomes[outcome] = outcomes.get(outcome, 0) + n
    print(f'\nparameter sets: {sum(outcomes.values())} ({", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))})')
    calls: dict[str, int] = {}
    for key, n in numbers['service_calls'].items():
        outcome = key.rsplit(' ', 1)[1]
        calls[outcome] = calls.get(outcome, 0) + n
    print(f'service calls: {sum(calls.values())} ({", ".join(f"{k} {v}" for k, v in sorted(calls.items()))})')
    print(f'node processes alive: {len(numbers["alive"])}, crashes: {numbers["crashes"]}')
    print(f'callback errors logged (caught, the node went on): {numbers["callback_errors_logged"]}')
    return result.returncode


if __name__ == '__main__':
    raise SystemExit(main())
