"""Smoke test of bench/ros_chain.py, the bare-rclpy baseline other benchmarks import: every
variant sets up, goes round the ring and tears down (children included) without hanging.
It leases its own ROS domain, so it needs no fixture."""
import importlib.util
import math
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent.parent / 'bench' / 'ros_chain.py'


@pytest.fixture(scope='module')
def ros_chain():
    spec = importlib.util.spec_from_file_location('ros_chain', BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize('executor', ['single', 'events'])
@pytest.mark.parametrize('multiprocess', [False, True], ids=['one_process', 'process_per_node'])
def test_bare_chain_runs_and_reports_a_rate(ros_chain, multiprocess, executor):
    rate = ros_chain.bare_chain_rate(hops=2, steps=100, multiprocess=multiprocess, executor=executor, warmup=10)
    assert math.isfinite(rate) and rate > 0      # a rate, not a bound on it (no timed assertions)


def test_the_relays_are_stopped_cleanly(ros_chain):
    with ros_chain.Chain(hops=3, multiprocess=True, executor='events') as chain:
        chain.measure(10)
        supervisor = chain.supervisor
    assert supervisor.alive() == []
    codes = {name: child.returncode for name, child in supervisor.children.items()}
    tails = {name: child.tail(200) for name, child in supervisor.children.items() if codes[name] != 0}
    # SIGINT was enough: a clean exit (or what the one that was not printed, run114)
    assert codes == {'chain_relay_1': 0, 'chain_relay_2': 0}, tails
