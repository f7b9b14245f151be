"""A real `pip install` of the package lays out an ament_python prefix: the package marker
in the ament index, package.xml and config under share/, the executables under
lib/machine_ctrl/ (where `ros2 run` looks) as well as bin/."""
import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def console_scripts():
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], 'id', '') == 'EXECUTABLES':
            return ast.literal_eval(node.value)
    raise AssertionError('setup.py has no EXECUTABLES')


@pytest.fixture(scope='module')
def prefix(tmp_path_factory):
    # --ignore-installed: without it pip would first uninstall the venv's own (editable) copy
    prefix = tmp_path_factory.mktemp('prefix')
    subprocess.run([sys.executable, '-m', 'pip', 'install', '--no-deps', '--no-build-isolation',
                    '--disable-pip-version-check', '-q', '--ignore-installed', '--prefix', str(prefix), str(ROOT)],
                   check=True, capture_output=True, timeout=300)
    return prefix


def test_ament_index_marker_and_share(prefix):
    assert (prefix / 'share/ament_index/resource_index/packages/machine_ctrl').is_file()
    assert (prefix / 'share/machine_ctrl/package.xml').is_file()
    for name in ('micromill_9axis', 'trt_5axis'):
        assert (prefix / f'share/machine_ctrl/config/machines/{name}.yaml').is_file()
        assert (prefix / f'share/machine_ctrl/config/machines/{name}.urdf').is_file()


def test_every_executable_is_in_lib_and_bin(prefix):
    scripts = console_scripts()
    assert sorted(p.name for p in (ROOT / 'lib_scripts').iterdir()) == sorted(scripts)
    for name, target in scripts.items():
        module, function = target.split(':')
        launcher = prefix / 'lib/machine_ctrl' / name
        assert launcher.is_file() and os.access(launcher, os.X_OK), launcher
        assert f'from {module} import {function}' in launcher.read_text()
        assert (prefix / 'bin' / name).is_file()


def test_installed_launcher_runs_from_the_prefix_alone(prefix, tmp_path):
    site = next(prefix.glob('lib/python3*/site-packages'))
    env = {**os.environ, 'PYTHONPATH': str(site), 'AMENT_PREFIX_PATH': str(prefix)}
    result = subprocess.run([sys.executable, str(prefix / 'lib/machine_ctrl/machine-ctrl'), 'info', '--json'],
                            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert result.returncode == 0, result.stderr
    assert '"micromill_9axis"' in result.stdout
