"""Lay out this checkout's ament files in a prefix (the dev venv), as
`colcon build --symlink-install` does: the editable install puts none of them there.

    python dev/ament_layout.py PREFIX

makes symlinks into the checkout, one per file:
  PREFIX/share/ament_index/resource_index/packages/machine_ctrl   -> resource/machine_ctrl
  PREFIX/share/machine_ctrl/package.xml                           -> package.xml
  PREFIX/share/machine_ctrl/config/**                             -> config/**
  PREFIX/share/machine_ctrl/launch/<name>.launch.py               -> launch/<name>.launch.py
  PREFIX/lib/machine_ctrl/<executable>                            -> lib_scripts/<executable>
so that with AMENT_PREFIX_PATH=PREFIX `ros2 run machine_ctrl hw_sim_node` and
`ros2 launch machine_ctrl bringup.launch.py` use the checkout. Files, not directories, are
linked (as colcon does): `ros2 launch` finds launch files with os.walk, which does not enter
linked directories. The same files as setup.py's data_files (test/test_install_layout.py
compares the two); the executables are read from setup.py's EXECUTABLES. The launchers run
PREFIX/bin/<executable>, the console scripts of the editable install.

Idempotent: what is already right is left alone, and what is no longer wanted under
share/machine_ctrl and lib/machine_ctrl (a file or executable removed from the checkout) is
removed. Standard library only; dev/_venv.sh runs it on every run (a few milliseconds).
"""
import ast
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = 'machine_ctrl'


def executables(root: Path = ROOT) -> list[str]:
    """The names in setup.py's EXECUTABLES (read, not run: setup.py calls setup())."""
    for node in ast.walk(ast.parse((root / 'setup.py').read_text())):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], 'id', '') == 'EXECUTABLES':
            return list(ast.literal_eval(node.value))
    raise SystemExit(f'{root / "setup.py"}: no EXECUTABLES')


def _share_files(root: Path, folder: str, pattern: str) -> list[Path]:
    """The files setup.py installs from folder (its _share_data_files)."""
    return sorted(f for f in (root / folder).glob(pattern) if f.is_file() and '__pycache__' not in f.parts)


def wanted_links(prefix: Path, root: Path = ROOT) -> dict[Path, Path]:
    """link -> target (a file of the checkout) for every entry of the layout."""
    share = prefix / 'share' / PACKAGE
    links = {prefix / 'share/ament_index/resource_index/packages' / PACKAGE: root / 'resource' / PACKAGE,
             share / 'package.xml': root / 'package.xml'}
    for folder, pattern in (('config', '**/*'), ('launch', '*.launch.py')):
        for f in _share_files(root, folder, pattern):
            links[share / f.relative_to(root)] = f
    for name in executables(root):
        links[prefix / 'lib' / PACKAGE / name] = root / 'lib_scripts' / name
    return links


def _own_dirs(prefix: Path) -> list[Path]:
    """The folders only this package writes in."""
    return [prefix / 'share' / PACKAGE, prefix / 'lib' / PACKAGE]


def _make_parents(link: Path, prefix: Path) -> None:
    """Real directories down to link's folder. A linked directory inside our own folders (an
    older layout linked config/) is unlinked first: writing through it would replace the
    checkout's files with links to themselves."""
    own = _own_dirs(prefix)
    folder = link.parent
    for d in reversed([folder, *folder.parents]):
        if any(d == o or o in d.parents for o in own) and d.is_symlink():
            d.unlink()
    folder.mkdir(parents=True, exist_ok=True)


def _link(link: Path, target: Path, prefix: Path) -> bool:
    """Make link point at target; False when it already did."""
    if link.is_symlink() and Path(os.readlink(link)) == target and not link.parent.is_symlink():
        return False
    _make_parents(link, prefix)
    if link.is_dir() and not link.is_symlink():
        raise SystemExit(f'{link}: a directory where the layout wants a file; remove it')
    tmp = link.with_name(f'.{link.name}.{os.getpid()}.tmp')
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(target)
    os.replace(tmp, link)  # atomic: a concurrent reader sees the old link or the new one
    return True


def _remove_stale(prefix: Path, links: dict[Path, Path]) -> list[Path]:
    """Remove what is under our own folders but not in links; empty folders too."""
    removed = []
    for top in _own_dirs(prefix):
        if top.is_symlink():
            top.unlink()
            removed.append(top)
            continue
        for dirpath, dirnames, filenames in os.walk(top, topdown=False):  # does not enter links
            for name in filenames + dirnames:
                path = Path(dirpath) / name
                if path in links:
                    continue
                if path.is_symlink() or path.is_file():
                    path.unlink()
                    removed.append(path)
                elif path.is_dir() and not any(path.iterdir()):
                    path.rmdir()
    return removed


def lay_out(prefix: Path, root: Path = ROOT) -> list[str]:
    """Make the layout under prefix; returns what changed, one line per entry."""
    prefix = Path(prefix).absolute()
    links = wanted_links(prefix, root)
    changed = [f'{link} removed' for link in _remove_stale(prefix, links)]
    changed += [f'{link} -> {target}' for link, target in links.items() if _link(link, target, prefix)]
    return changed


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print('usage: python dev/ament_layout.py PREFIX', file=sys.stderr)
        return 2
    changed = lay_out(Path(argv[0]))
    if changed:
        print(f'ament layout in {argv[0]}: {len(changed)} entries updated', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
