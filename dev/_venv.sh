# Sourced by dev/demo and dev/test: creates .venv with the pinned dependencies and the
# package (editable), once per change of requirements.txt / setup.py / package.xml.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${MACHINE_CTRL_VENV:-$ROOT/.venv}"
PY="$(command -v python3.11 || command -v python3)"
"$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' \
  || { echo "machine_ctrl needs Python 3.11 (the ROS 2 Jazzy wheels are built for it); found $("$PY" --version)" >&2; exit 2; }
stamp="$VENV/.machine_ctrl-installed"
want="$(cat "$ROOT/requirements.txt" "$ROOT/setup.py" "$ROOT/setup.cfg" "$ROOT/package.xml" | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setting up $VENV (pinned dependencies, one-time)..." >&2
  [ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
  log="$VENV/pip-install.log"
  { "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$ROOT/requirements.txt" &&
    "$VENV/bin/python" -m pip install --disable-pip-version-check --no-deps --no-build-isolation -e "$ROOT"
  } > "$log" 2>&1 || { tail -n 30 "$log" >&2; echo "pip install failed; full log: $log" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
# Message definitions and the package index live under the venv prefix (design.md, "ROS specifics").
export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export PATH="$VENV/bin:$PATH"
