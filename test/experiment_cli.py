"""Shared test check: `machine-ctrl experiment NAME --json --plots DIR` as a user runs it (the
CLI wiring of an experiment): exit 0, status ok, every file written a PNG."""
import json
import subprocess
import sys
from pathlib import Path

PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def experiment_json(name: str, plots: Path, timeout: float = 300.0) -> dict:
    """The command's JSON, once it exited 0 with status ok and wrote only PNGs into `plots`
    (the caller checks their names)."""
    exe = Path(sys.executable).parent / 'machine-ctrl'
    result = subprocess.run([str(exe), 'experiment', name, '--json', '--plots', str(plots)],
                            capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert data['status'] == 'ok', data
    for path in plots.iterdir():
        assert path.read_bytes()[:8] == PNG_SIGNATURE, path
    return data
