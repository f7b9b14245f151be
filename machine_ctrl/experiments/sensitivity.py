"""How Tables 6.1 / 6.2 on the simulated micromill depend on the two plant values that were
chosen to come near them (issue [8/8] part 4, the outside audit): the guideway bristles'
stiffness sigma0 (10x Table 4.3's tuned value, config/machines/micromill_9axis.yaml) and the
table's force noise (plant.force_noise, calibrated against one named figure: the ~200 nm
the CIRP paper reports for the table's translations, section 5). Each is halved and doubled
alone, everything else as configured; sigma1 follows sigma0 by the rule the config states
(critical damping, thesis Eq. 4.65: 2 sqrt(m sigma0) - b, with the plant's m and b).

    machine-ctrl experiment circle|square --sensitivity [--steps N] [--jobs N]

:func:`friction_levels` varies the friction of one kind of axis for `experiment contour
--sensitivity` (Sencer's trt_5axis, whose friction levels are all assumed).

The result: per variant the SMC and DSFD statistics (tracking.contouring; the contour
control's runs are left out) and each one's ratio to the configured run's (None where the
configured statistic is 0, as on a run too short to move).
"""
from __future__ import annotations

import math
from dataclasses import replace

from machine_ctrl.model.config import MachineConfig

# (label, factor on sigma0, factor on the force noise)
VARIANTS = (('sigma0 x 0.5', 0.5, 1.0), ('sigma0 x 2', 2.0, 1.0),
            ('force noise x 0.5', 1.0, 0.5), ('force noise x 2', 1.0, 2.0))


def varied(machine: MachineConfig, sigma0: float = 1.0, force_noise: float = 1.0) -> MachineConfig:
    """`machine` with every plant's bristle stiffness times `sigma0` (sigma1 critical again,
    Eq. 4.65) and force noise times `force_noise`; the controllers' values as they were."""
    axes = []
    for axis in machine.axes:
        plant = axis.plant
        if plant is None:
            axes.append(axis)
            continue
        friction = plant.friction
        if friction is not None and sigma0 != 1.0:
            stiffness = friction.sigma0 * sigma0
            friction = replace(friction, sigma0=stiffness,
                               sigma1=max(2.0 * math.sqrt(plant.mass * stiffness) - plant.damping, 0.0))
        axes.append(replace(axis, plant=replace(plant, friction=friction, force_noise=plant.force_noise * force_noise)))
    return replace(machine, axes=tuple(axes))


def friction_levels(machine: MachineConfig, factor: float, kind: str) -> MachineConfig:
    """`machine` with the friction of its `kind` ('linear' or 'rotary') axes times `factor`:
    the static and Coulomb levels and sigma0 alike (the presliding distance level/sigma0 kept),
    sigma1 critical again (Eq. 4.65); the controllers' values as they were."""
    axes = []
    for axis in machine.axes:
        friction = None if axis.plant is None else axis.plant.friction
        if friction is None or axis.kind != kind:
            axes.append(axis)
            continue
        stiffness = friction.sigma0 * factor
        friction = replace(friction, static=tuple(f * factor for f in friction.static),
                           coulomb=tuple(f * factor for f in friction.coulomb), sigma0=stiffness,
                           sigma1=max(2.0 * math.sqrt(axis.plant.mass * stiffness) - axis.plant.damping, 0.0))
        axes.append(replace(axis, plant=replace(axis.plant, friction=friction)))
    return replace(machine, axes=tuple(axes))


def sensitivity(machine: MachineConfig, kind: str, steps: int | None = None, workers: int | None = None,
                progress=None) -> dict:
    """{'configured': contouring result, 'variants': {label: {'smc', 'dsfd', 'ratio': {mode:
    {statistic: variant / configured}}}}} for the circle or the square (`kind`)."""
    from machine_ctrl.experiments.tracking import contouring
    configured = contouring(machine, kind, progress=progress, steps=steps, workers=workers)
    variants = {}
    for label, stiffness, noise in VARIANTS:
        run = contouring(varied(machine, stiffness, noise), kind, progress=progress, steps=steps, workers=workers)
        variants[label] = {'smc': run['smc'], 'dsfd': run['dsfd'],
                           'ratio': {mode: {key: run[mode][key] / configured[mode][key] if configured[mode][key] else None
                                            for key in run[mode]} for mode in ('smc', 'dsfd')}}
    return {'configured': configured, 'variants': variants}


def table(kind: str, result: dict) -> str:
    """Each statistic (um) of SMC and DSFD: configured, then each variant's ratio to it."""
    from machine_ctrl.experiments.tracking import STAT_KEYS
    labels = [label for label, _, _ in VARIANTS]
    lines = [f'{kind}: sensitivity to the plant values chosen to come near the thesis (ratio to the configured run)',
             f'  {"statistic":24s} {"configured um":>14s} ' + ' '.join(f'{label:>17s}' for label in labels)]
    for mode in ('smc', 'dsfd'):
        for key in STAT_KEYS:
            ratios = ' '.join('n/a'.rjust(17) if (r := result['variants'][label]['ratio'][mode][key]) is None
                              else f'{r:17.2f}' for label in labels)
            lines.append(f'  {mode + " " + key:24s} {result["configured"][mode][key]:14.3f} {ratios}')
    return '\n'.join(lines)
