"""Geometric error compensation throughput (issue [6/7]: faster than the 10 kHz control
rate, so it can run online): rows of a circle reference per second of CPU time through
Compensator.compensate_rows (Algorithm 2 + Taylor neighbours for v, a), in chunks of 500
rows as compensation_node receives them.

    .venv/bin/python bench/compensation_rate.py
"""
import time

from compensation.compensate import Compensator
from compensation.error_map import load_error_map
from machine_ctrl.model.config import load_machine
from trajectory.contours import contour_reference

CHUNK = 500


def main() -> None:
    machine = load_machine('micromill_9axis')
    error_map = load_error_map(machine.simulation.error_map_path(machine.yaml_path), machine.axis_names)
    compensator = Compensator.from_map(machine, error_map)
    ref = contour_reference(machine, 'circle')
    rows = 20 * CHUNK
    start = time.process_time()
    for first in range(0, rows, CHUNK):
        k = slice(first, first + CHUNK)
        compensator.compensate_rows(ref.position[k], ref.velocity[k], ref.acceleration[k])
    cpu = time.process_time() - start
    print(f'{rows / cpu:.0f} rows/s of CPU time ({cpu / rows * 1e6:.1f} us/row; '
          f'control rate {1 / machine.control_period:.0f} rows/s)')


if __name__ == '__main__':
    main()
