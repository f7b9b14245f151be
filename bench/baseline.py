"""What the benchmarks that compare this tree with a baseline revision share: the baseline
checked out into a temporary git worktree, and one measurement in a fresh Python with a
tree first on its path (so both are run by the same interpreter, one after the other, under
the same machine load)."""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def labelled_trees(stack: contextlib.ExitStack, revision: str | None) -> dict[str, Path | None]:
    """{label: tree} a bench measures: this tree as installed (label '', tree None), or with
    `revision` the baseline's worktree (removed when `stack` closes) and this tree, in that
    order, labelled for the bench's lines."""
    if revision is None:
        return {'': None}
    return {f' (baseline {revision})': stack.enter_context(worktree(revision)), ' (this tree)': ROOT}


def tree_env(tree: Path | None) -> dict | None:
    """The environment whose Python imports machine_ctrl from `tree` (None: as installed):
    for a supervisor that starts nodes of either tree."""
    return None if tree is None else dict(os.environ, PYTHONPATH=str(tree))


@contextlib.contextmanager
def worktree(revision: str):
    """The path of a temporary worktree of `revision`, removed on leaving (SystemExit naming
    the revision when git has none)."""
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / 'baseline'
        added = subprocess.run(['git', '-C', str(ROOT), 'worktree', 'add', '--detach', str(base), revision],
                               capture_output=True, text=True)
        if added.returncode:
            raise SystemExit(f'no baseline {revision}: {added.stderr.strip()}')
        try:
            yield base
        finally:
            subprocess.run(['git', '-C', str(ROOT), 'worktree', 'remove', '--force', str(base)], check=False,
                           capture_output=True)


def child_json(tree: Path, code: str, *args: str, what: str = 'the measurement') -> dict:
    """Run `code` (with `args`) in a fresh Python with `tree` first on its path; the JSON
    object on the last line it prints. SystemExit with its stderr when it fails."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run([sys.executable, '-c', code, *args], cwd=tree, env=env, capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(f'{what} in {tree} failed:\n{out.stderr}')
    return json.loads(out.stdout.strip().splitlines()[-1])


def alternate(runs: int, baseline: Path, measure) -> dict[str, list]:
    """{'baseline': [...], 'this tree': [...]}: `measure(which, tree)` `runs` times in each tree,
    alternating run by run so that both see the same machine load; `measure` may print."""
    results = {'baseline': [], 'this tree': []}
    for _ in range(runs):
        for which, tree in (('baseline', baseline), ('this tree', ROOT)):
            results[which].append(measure(which, tree))
    return results
