"""The package installs like a ROS package.

A real `pip install` into a prefix lays out an ament_python prefix: the package marker in the
ament index, package.xml, config and launch files under share/, the console scripts in bin/
and the `ros2 run` launchers in lib/machine_ctrl/, which run with the interpreter the package
was installed with (no python3 on PATH needed). Its Requires-Dist names every third-party
distribution the code imports, and the dev venv's lock satisfies it. dev/ament_layout.py lays
the same files out in the dev venv as links into the checkout."""
import ast
import importlib.metadata
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
RUNTIME_PACKAGES = ('machine_ctrl', 'trajectory', 'compensation', 'hw_sim')
# Import names that importlib.metadata.packages_distributions() cannot map (the
# distribution's RECORD does not name the module as a top-level package).
IMPORT_TO_DISTRIBUTION = {'pinocchio': 'pin', 'ruckig': 'ruckig'}


def setup_value(name):
    tree = ast.parse((ROOT / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], 'id', '') == name:
            return ast.literal_eval(node.value)
    raise AssertionError(f'setup.py has no {name}')


def normalized(name):
    return re.sub(r'[-_.]+', '-', name).lower()


def ament_layout():
    spec = importlib.util.spec_from_file_location('ament_layout', ROOT / 'dev/ament_layout.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope='module')
def prefix(tmp_path_factory):
    # --ignore-installed: without it pip would first uninstall the venv's own (editable) copy
    prefix = tmp_path_factory.mktemp('prefix')
    done = subprocess.run([sys.executable, '-m', 'pip', 'install', '--no-deps', '--no-build-isolation',
                           '--disable-pip-version-check', '-q', '--ignore-installed', '--prefix', str(prefix),
                           str(ROOT)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return prefix


@pytest.fixture
def no_python_on_path(tmp_path):
    """An environment whose PATH holds only a python3 (and python, python3.11) that fails:
    as a ROS user's shell without the venv, where `python3` is some other interpreter."""
    bin_dir = tmp_path / 'path-bin'
    bin_dir.mkdir()
    for name in ('python', 'python3', 'python3.11'):
        stub = bin_dir / name
        stub.write_text('#!/bin/sh\necho "the python3 on PATH was used" >&2\nexit 97\n')
        stub.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if k not in ('VIRTUAL_ENV', 'PYTHONHOME', 'PYTHONPATH')}
    return {**env, 'PATH': str(bin_dir)}


def site_packages(prefix):
    return next(prefix.glob('lib/python3*/site-packages'))


def installed_files(top):
    """Files under top (relative), compiled Python left out."""
    return sorted(str(p.relative_to(top)) for p in top.rglob('*')
                  if (p.is_file() or p.is_symlink()) and '__pycache__' not in p.parts)


def test_ament_index_marker_and_share(prefix):
    assert (prefix / 'share/ament_index/resource_index/packages/machine_ctrl').is_file()
    assert (prefix / 'share/machine_ctrl/package.xml').is_file()
    for name in ('micromill_9axis', 'trt_5axis', 'fts_lathe'):
        assert (prefix / f'share/machine_ctrl/config/machines/{name}.yaml').is_file()
        assert (prefix / f'share/machine_ctrl/config/machines/{name}.urdf').is_file()
    config = sorted(str(p.relative_to(ROOT)) for p in (ROOT / 'config').rglob('*') if p.is_file())
    assert installed_files(prefix / 'share/machine_ctrl/config') == [str(Path(c).relative_to('config')) for c in config]
    launch = sorted(p.name for p in (ROOT / 'launch').glob('*.launch.py'))
    share_launch = prefix / 'share/machine_ctrl/launch'
    assert (installed_files(share_launch) if share_launch.is_dir() else []) == launch


def test_every_executable_has_a_launcher_that_runs_its_console_script(prefix):
    scripts = setup_value('EXECUTABLES')
    assert sorted(p.name for p in (ROOT / 'lib_scripts').iterdir()) == sorted(scripts)
    for name, target in scripts.items():
        module, function = target.split(':')
        launcher = prefix / 'lib/machine_ctrl' / name
        assert launcher.is_file() and os.access(launcher, os.X_OK), launcher
        text = launcher.read_text()
        assert text.startswith('#!/bin/sh\n'), launcher
        assert f'/../../bin/{name}\n' in text and 'exec "$script" "$@"' in text, launcher
        console_script = prefix / 'bin' / name
        assert os.access(console_script, os.X_OK), console_script
        lines = console_script.read_text().splitlines()
        # the interpreter pip installed with, by absolute path (a long path gets pip's
        # /bin/sh wrapper, which names it on the next line)
        assert sys.executable in lines[0] or (lines[0] == '#!/bin/sh' and sys.executable in lines[1]), lines[:2]
        assert f'from {module} import {function}' in console_script.read_text()


def test_installed_launcher_runs_without_python_on_path(prefix, no_python_on_path, tmp_path):
    env = {**no_python_on_path, 'PYTHONPATH': str(site_packages(prefix)), 'AMENT_PREFIX_PATH': str(prefix)}
    result = subprocess.run([str(prefix / 'lib/machine_ctrl/machine-ctrl'), 'info', '--json'],
                            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert result.returncode == 0, result.stderr
    assert '"micromill_9axis"' in result.stdout


def test_launcher_without_its_console_script_says_so(tmp_path):
    lib = tmp_path / 'lib/machine_ctrl'
    lib.mkdir(parents=True)
    launcher = lib / 'hw_sim_node'
    launcher.write_text((ROOT / 'lib_scripts/hw_sim_node').read_text())
    launcher.chmod(0o755)
    result = subprocess.run([str(launcher)], capture_output=True, text=True, timeout=30)
    assert result.returncode == 127
    assert 'no console script' in result.stderr and 'bin/hw_sim_node' in result.stderr


def ros2():
    path = Path(sys.executable).parent / 'ros2'
    if not path.exists():
        pytest.skip('no ros2 command line in this venv (../shared/ros2-tools/install adds it; dev/_venv.sh does)')
    return path


def test_ros2_run_runs_the_installed_launcher(prefix, no_python_on_path, tmp_path):
    env = {**no_python_on_path, 'PYTHONPATH': str(site_packages(prefix)), 'AMENT_PREFIX_PATH': str(prefix)}
    where = subprocess.run([str(ros2()), 'pkg', 'prefix', 'machine_ctrl'],
                           capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert where.stdout.strip() == str(prefix), where.stderr
    result = subprocess.run([str(ros2()), 'run', 'machine_ctrl', 'machine-ctrl', 'info', '--json'],
                            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert result.returncode == 0, result.stderr
    assert '"micromill_9axis"' in result.stdout


SOURCE = ('setup.py', 'setup.cfg', 'package.xml', 'resource', 'lib_scripts', 'config', 'launch',
          *RUNTIME_PACKAGES)


def test_colcon_build_installs_launchers_that_run(no_python_on_path, tmp_path):
    """`colcon build` of the package (a copy of the checkout in a workspace) in this venv."""
    colcon = Path(sys.executable).parent / 'colcon'
    if not colcon.exists():
        pytest.skip('colcon is not installed in this venv (pip install colcon-common-extensions)')
    src = tmp_path / 'ws/src/machine_ctrl'
    for name in SOURCE:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns('__pycache__'))
        elif (ROOT / name).exists():
            src.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    env = {**os.environ, 'PATH': f'{colcon.parent}{os.pathsep}{os.environ["PATH"]}'}
    build = subprocess.run([str(colcon), 'build'], cwd=tmp_path / 'ws', env=env,
                           capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout + build.stderr
    installed = tmp_path / 'ws/install/machine_ctrl'
    assert installed_files(installed / 'lib/machine_ctrl') == sorted(setup_value('EXECUTABLES'))
    assert (installed / 'share/ament_index/resource_index/packages/machine_ctrl').is_file()
    env = {**no_python_on_path, 'PYTHONPATH': str(site_packages(installed)), 'AMENT_PREFIX_PATH': str(installed)}
    result = subprocess.run([str(installed / 'lib/machine_ctrl/machine-ctrl'), 'info', '--json'],
                            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert result.returncode == 0, result.stderr
    assert '"micromill_9axis"' in result.stdout


def runtime_imports():
    """{top-level module name: first file importing it} of the runtime packages, lazy imports included."""
    found = {}
    for package in RUNTIME_PACKAGES:
        for path in sorted((ROOT / package).rglob('*.py')):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    found.setdefault(name.split('.')[0], str(path.relative_to(ROOT)))
    return {name: where for name, where in found.items()
            if name not in sys.stdlib_module_names and name not in RUNTIME_PACKAGES}


def requires_dist(prefix):
    """The installed metadata's unconditional requirements."""
    dist = next(importlib.metadata.distributions(path=[str(site_packages(prefix))], name='machine_ctrl'))
    return [r for r in map(Requirement, dist.requires or []) if r.marker is None]


def test_requires_dist_names_every_third_party_import(prefix):
    required = {normalized(r.name) for r in requires_dist(prefix)}
    by_module = importlib.metadata.packages_distributions()
    imports = runtime_imports()
    assert {'numpy', 'rclpy', 'yaml', 'mcap', 'pinocchio'} <= set(imports)  # the walk sees them
    missing = []
    for module, where in sorted(imports.items()):
        candidates = by_module.get(module) or [IMPORT_TO_DISTRIBUTION.get(module, '')]
        if not any(normalized(c) in required for c in candidates if c):
            missing.append(f'{where} imports {module} (distribution {" or ".join(candidates) or "unknown"})')
    assert not missing, 'add to setup.py REQUIRES (and package.xml): ' + '; '.join(missing)


def test_the_lock_satisfies_requires_dist(prefix):
    """The dev venv, installed from requirements.txt, is inside every range of setup.py."""
    outside = []
    for requirement in requires_dist(prefix):
        try:
            version = importlib.metadata.version(requirement.name)
        except importlib.metadata.PackageNotFoundError:
            outside.append(f'{requirement}: not installed')
            continue
        if not requirement.specifier.contains(version, prereleases=True):
            outside.append(f'{requirement}: {version} installed')
    assert not outside, outside


# --- the dev venv's layout (dev/ament_layout.py) ---

def test_dev_layout_has_the_files_of_the_install(prefix, tmp_path):
    layout = ament_layout()
    dev = tmp_path / 'dev-prefix'
    assert layout.lay_out(dev)
    for sub in ('share/machine_ctrl', 'lib/machine_ctrl', 'share/ament_index'):
        assert installed_files(dev / sub) == installed_files(prefix / sub), sub
    for link, target in layout.wanted_links(dev).items():
        assert link.is_symlink() and link.resolve() == target.resolve(), link
        assert target.is_file() and ROOT in target.parents, target
    assert layout.lay_out(dev) == []  # idempotent


def test_dev_layout_replaces_an_older_one_and_leaves_the_checkout_alone(tmp_path):
    root = tmp_path / 'checkout'
    files = {'setup.py': "EXECUTABLES = {'a_node': 'x:main'}\n", 'package.xml': '<package/>\n',
             'resource/machine_ctrl': '', 'config/machines/m.yaml': 'name: m\n',
             'lib_scripts/a_node': '#!/bin/sh\n', 'launch/x.launch.py': '# launch\n'}
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    prefix = tmp_path / 'prefix'
    (prefix / 'share/machine_ctrl').mkdir(parents=True)
    (prefix / 'lib/machine_ctrl').mkdir(parents=True)
    (prefix / 'share/machine_ctrl/config').symlink_to(root / 'config')  # a linked folder
    (prefix / 'lib/machine_ctrl/removed_node').symlink_to(root / 'lib_scripts/a_node')
    (prefix / 'share/machine_ctrl/stale.txt').write_text('copy of an old install\n')

    ament_layout().lay_out(prefix, root)
    for name, text in files.items():  # every checkout file still a file with its text
        assert not (root / name).is_symlink() and (root / name).read_text() == text, name
    assert sorted(installed_files(prefix)) == [
        'lib/machine_ctrl/a_node', 'share/ament_index/resource_index/packages/machine_ctrl',
        'share/machine_ctrl/config/machines/m.yaml', 'share/machine_ctrl/launch/x.launch.py',
        'share/machine_ctrl/package.xml']
    assert not (prefix / 'share/machine_ctrl/config').is_symlink()
    (root / 'launch/x.launch.py').unlink()
    ament_layout().lay_out(prefix, root)
    assert not (prefix / 'share/machine_ctrl/launch').exists()


def test_dev_venv_runs_ros2_run_on_the_checkout(no_python_on_path, tmp_path):
    """In the dev venv (dev/_venv.sh lays it out), `ros2 run` finds the checkout's launchers."""
    if not (Path(sys.prefix) / 'share/ament_index/resource_index/packages/machine_ctrl').exists():
        pytest.skip(f'{sys.prefix} has no ament layout (dev/_venv.sh makes it)')
    env = {**no_python_on_path, 'AMENT_PREFIX_PATH': sys.prefix}
    result = subprocess.run([str(ros2()), 'run', 'machine_ctrl', 'machine-ctrl', 'info', '--json'],
                            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=60)
    assert result.returncode == 0, result.stderr
    assert '"micromill_9axis"' in result.stdout
