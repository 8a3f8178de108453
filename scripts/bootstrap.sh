#!/usr/bin/env bash
# Create .venv with everything mlsemreg_ros needs, Debian packages included.
# Idempotent: re-running only installs what changed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${VENV:-.venv}

quiet_pip() {  # this machine's pip config names find-links folders that may not exist
  "$VENV/bin/pip" "$@" 2> >(grep -v "^WARNING: Location 'file://" >&2)
}

need=()
"$PY" -c 'import ensurepip, venv' 2>/dev/null || need+=(python3-venv)
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || need+=(libusb-1.0-0)   # open3d-cpu
ldconfig -p 2>/dev/null | grep -q 'libgomp.so.1' || need+=(libgomp1)          # open3d-cpu
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "mlsemreg_ros setup needs the Debian packages: ${need[*]}" >&2
    echo "Run this command as root, or first: sudo apt-get install -y ${need[*]}" >&2
    exit 1
  fi
  echo "Installing Debian packages: ${need[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi

# PostgreSQL server for the multi-worker tuning test (test/test_tune_postgres.py): optional,
# that test is skipped with a message where it is missing.
if ! ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1; then
  if [ "$(id -u)" -eq 0 ]; then
    echo "Installing Debian package: postgresql (for the tuning test on a real database server)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null \
      || echo "postgresql could not be installed: test/test_tune_postgres.py will be skipped" >&2
  else
    echo "Note: the Debian package postgresql is missing and this is not root:" >&2
    echo "  test/test_tune_postgres.py will be skipped (sudo apt-get install -y postgresql)" >&2
  fi
fi

[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
stamp="$VENV/.mlsemreg-installed"
want=$(cat requirements.txt requirements-nodeps.txt setup.py | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "Installing Python packages into $VENV (first time: a few minutes)"
  quiet_pip install -q --upgrade pip
  quiet_pip install -q -r requirements.txt
  quiet_pip install -q --no-deps -r requirements-nodeps.txt   # peers with stale pins
  quiet_pip install -q --no-deps -e .
  echo "$want" > "$stamp"
fi
"$VENV/bin/python" -c 'import open3d, rclpy, rosbags, mlsemreg_ros' \
  || { echo "setup finished but imports fail; see above" >&2; exit 1; }
