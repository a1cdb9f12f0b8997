#!/usr/bin/env bash
# One entry point for a fresh machine:
#   bash setup.sh quickstart   install, then run the quickstart recipe
#   bash setup.sh test         install, then run the test suite (what CI runs)
# The virtualenv lives outside the clone (reused by every clone on this machine); override with ADADEMO_VENV.
set -euo pipefail
cd "$(dirname "$0")"
VENV="${ADADEMO_VENV:-$HOME/.venvs/adademo-lerobot}"
PYTHON="${PYTHON:-python3.11}"
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3

if [ ! -x "$VENV/bin/python" ]; then
  echo "creating virtualenv $VENV (first install downloads ~9 GB: lerobot + torch, about 5 minutes)"
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/pip" install --quiet --upgrade pip
fi
"$VENV/bin/pip" install --quiet -e ".[test]" 2>&1 | grep -v -E "^(WARNING|  )" || true
"$VENV/bin/python" -c "import adademo_lerobot, lerobot, metaworld, gymnasium_robotics" \
  || { echo "error: the install into $VENV failed; see pip's output above"; exit 1; }

# Camera images on machines without a GPU render with OSMesa (tests of pixels_state need it).
if ! ldconfig -p 2>/dev/null | grep -q libOSMesa && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  echo "installing libosmesa6 (CPU rendering for --suite.obs_type=pixels_state)"
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6) >/dev/null 2>&1 \
    || echo "warning: could not install libosmesa6; pixel observations will not render on this machine"
fi

# Two cores: keep torch from oversubscribing them beside env worker processes (see README, "Threads").
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-2}"

case "${1:-}" in
  test)
    shift
    exec "$VENV/bin/python" -m pytest -q "$@"
    ;;
  quickstart)
    shift
    exec "$VENV/bin/adademo-run" --config_path=recipes/quickstart.yaml --run_dir=outputs/quickstart "$@"
    ;;
  *)
    echo "usage: bash setup.sh test|quickstart [extra flags]" >&2
    exit 2
    ;;
esac
