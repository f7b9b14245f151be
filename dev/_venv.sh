# Sourced by dev/demo and dev/test: creates .venv with the pinned dependencies, the package
# (editable) and, where ../shared/ros2-tools exists beside the checkout, the ros2 command line
# and launch; once per change of any of them. Then lays out the package's ament files in the
# venv (dev/ament_layout.py: symlinks, as colcon --symlink-install) on every run.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${MACHINE_CTRL_VENV:-$ROOT/.venv}"
PY="$(command -v python3.11 || command -v python3)"
"$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' \
  || { echo "machine_ctrl needs Python 3.11 (the ROS 2 Jazzy wheels are built for it); found $("$PY" --version)" >&2; exit 2; }
ROS2_TOOLS="$ROOT/../shared/ros2-tools"
[ -x "$ROS2_TOOLS/install" ] || ROS2_TOOLS=""
stamp="$VENV/.machine_ctrl-installed"
want="$( { cat "$ROOT/requirements.txt" "$ROOT/setup.py" "$ROOT/setup.cfg" "$ROOT/package.xml"
           if [ -n "$ROS2_TOOLS" ]; then sha256sum "$ROS2_TOOLS/install" "$ROS2_TOOLS"/wheels/* || true; else echo "no ros2-tools"; fi
         } | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setting up $VENV (pinned dependencies, one-time)..." >&2
  [ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
  log="$VENV/pip-install.log"
  { "$VENV/bin/python" -m pip install --disable-pip-version-check -r "$ROOT/requirements.txt" &&
    "$VENV/bin/python" -m pip install --disable-pip-version-check --no-deps --no-build-isolation -e "$ROOT" &&
    if [ -n "$ROS2_TOOLS" ]; then echo "+ $ROS2_TOOLS/install $VENV" && "$ROS2_TOOLS/install" "$VENV"; fi &&
    # the compiled redundancy resolution and offline loop into numba's cache now, not in the
    # first plans and runs (later changes to their source recompile at their first use)
    "$VENV/bin/python" -c 'from trajectory import resolved_rate; resolved_rate.warm()' &&
    "$VENV/bin/python" -c 'from hw_sim import offline; offline.warm()'
  } > "$log" 2>&1 || { tail -n 30 "$log" >&2; echo "venv setup failed; full log: $log" >&2; exit 1; }
  echo "$want" > "$stamp"
fi
"$VENV/bin/python" "$ROOT/dev/ament_layout.py" "$VENV"
# Message definitions and the package index live under the venv prefix (README "Quick start").
export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export PATH="$VENV/bin:$PATH"
