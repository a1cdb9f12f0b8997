#!/usr/bin/env bash
# One entry point for a fresh machine (see README, "Set up on a fresh machine"):
#   bash setup.sh quickstart [flags]   install from the lock file, then run the quickstart recipe
#   bash setup.sh test [pytest args]   install from the lock file, then lint and run the test suite (CI: .ci/run)
#   bash setup.sh install              only install (system packages, virtualenv from the lock)
#   bash setup.sh lock                 refresh requirements.lock from pyproject.toml's ranges (deliberately)
# The virtualenv lives outside the clone, in ~/.venvs/adademo-lerobot (override with ADADEMO_VENV); it always
# holds exactly the packages of requirements.lock: a venv that differs is re-synced, or refused if it cannot be.
set -euo pipefail
cd "$(dirname "$0")"
VENV="${ADADEMO_VENV:-$HOME/.venvs/adademo-lerobot}"
LOCK=requirements.lock
EXTRAS="test,ray,robot,so101"
# This checkout and its LeRobot plugin distributions (plugins/*: LeRobot finds them by their names), editable; and
# the examples the docs show, which the tests run: the env plugin of docs/lerobot-env.md with its broken variants
# (examples/lerobot_env_*) and the strategy plugin of docs/extending.md (examples/adademo_lerobot_example). None of
# them is in the lock.
EDITABLES=(-e ".[$EXTRAS]")
for plugin in plugins/*/ examples/*/; do EDITABLES+=(-e "$plugin"); done
# What pip freeze lists that the lock does not hold: pip itself, this checkout and the plugin/example distributions.
NOT_LOCKED='^(pip==|adademo-lerobot[ =@]|lerobot[-_](env|robot|teleoperator)[-_]adademo|lerobot[-_]env[-_]example|adademo[-_]lerobot[-_]example)'
# This machine's pip configuration may name local package folders that do not exist; pip warns about each.
pip_quiet() { "$@" 2> >(grep -v "^WARNING: Location 'file://" >&2); }

die() { echo "error: $*" >&2; exit 1; }

find_python() {
  # LeRobot 0.6 needs Python >= 3.12. pyenv machines: `PYENV_VERSION=3.12.1 python3.12`.
  local candidates=()
  [ -n "${PYTHON:-}" ] && candidates+=("$PYTHON")
  candidates+=(python3.12 python3.13 python3)
  for py in "${candidates[@]}"; do
    if command -v pyenv >/dev/null 2>&1 && [ -z "${PYENV_VERSION:-}" ] && [ "$py" = python3.12 ]; then
      local v
      v=$(pyenv versions --bare 2>/dev/null | grep -E '^3\.12(\.[0-9]+)?$' | sort -V | tail -1 || true)
      if [ -n "$v" ] && PYENV_VERSION="$v" "$py" -c 'import sys; assert sys.version_info >= (3, 12)' 2>/dev/null; then
        echo "env PYENV_VERSION=$v $py"; return
      fi
    fi
    if command -v "$py" >/dev/null 2>&1 && "$py" -c 'import sys; assert sys.version_info >= (3, 12)' 2>/dev/null; then
      echo "$py"; return
    fi
  done
  die "Python >= 3.12 is required (LeRobot 0.6 needs it) and none was found; install it (e.g. \`pyenv install 3.12\`) or set PYTHON=/path/to/python3.12"
}

install_system_packages() {
  # Before anything imports MuJoCo: CPU rendering of camera images (pixels_state) needs libOSMesa.
  if ldconfig -p 2>/dev/null | grep -q 'libOSMesa\.so'; then return; fi
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing libosmesa6 (CPU rendering for --suite.obs_type=pixels_state)"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6) >/dev/null 2>&1 \
      || die "could not install libosmesa6 with apt-get (needed to render camera images on a CPU machine)"
  elif [ "${CI:-}" = true ]; then
    die "CI needs libOSMesa (apt-get install libosmesa6) and cannot install it: not root or no apt-get"
  else
    echo "note: libOSMesa is not installed (apt-get install libosmesa6): state observations work, camera images" \
         "(pixels_state) will not render on this machine without a GPU"
  fi
}

lock_lines() { grep -v -E '^\s*(#|$)' "$LOCK" | sed 's/\s*#.*//' | tr '[:upper:]_' '[:lower:]-' | sort; }
installed_lines() {
  "$VENV/bin/python" -m pip freeze --all --exclude-editable 2>/dev/null | grep -v -E "$NOT_LOCKED" \
    | tr '[:upper:]_' '[:lower:]-' | sort
}

venv_matches_lock() { [ -x "$VENV/bin/python" ] && diff -q <(lock_lines) <(installed_lines) >/dev/null; }

install_venv() {
  [ -f "$LOCK" ] || die "$LOCK is missing: restore it from git (bash setup.sh lock makes a new one)"
  if [ ! -x "$VENV/bin/python" ]; then
    local py; py=$(find_python)
    echo "creating virtualenv $VENV with $($py --version 2>&1) (first install: ~6 GB, a few minutes)"
    $py -m venv "$VENV"
  fi
  "$VENV/bin/python" -c 'import sys; assert sys.version_info >= (3, 12)' 2>/dev/null \
    || die "$VENV has Python $("$VENV/bin/python" -V 2>&1 | cut -d' ' -f2); LeRobot 0.6 needs >= 3.12: delete it and rerun"
  if ! venv_matches_lock; then
    echo "installing the locked package set ($(lock_lines | wc -l) packages from $LOCK) into $VENV"
    pip_quiet "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -r "$LOCK" \
      || die "pip could not install $LOCK into $VENV; see pip's output above"
  fi
  # Reinstalled when this checkout or one of its plugin/example distributions is missing (or is another checkout's).
  local modules; modules=$(for d in plugins/*/ examples/*/; do basename "$d"; done | paste -sd,)
  if ! "$VENV/bin/python" -m pip show --quiet adademo-lerobot >/dev/null 2>&1 \
      || [ "$("$VENV/bin/python" -P -c 'import adademo_lerobot, os; print(os.path.dirname(os.path.dirname(adademo_lerobot.__file__)))' 2>/dev/null)" != "$PWD" ] \
      || ! "$VENV/bin/python" -P -c "import importlib.util, sys; sys.exit(any(importlib.util.find_spec(m) is None for m in '$modules'.split(',')))" 2>/dev/null; then
    pip_quiet "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation "${EDITABLES[@]}" \
      || die "pip could not install this checkout into $VENV; see pip's output above"
  fi
  if ! venv_matches_lock; then
    echo "$VENV differs from $LOCK (< lock, > installed):" >&2
    diff <(lock_lines) <(installed_lines) | grep '^[<>]' | head -20 >&2
    die "delete $VENV and rerun, or refresh the lock deliberately (bash setup.sh lock)"
  fi
  "$VENV/bin/python" -m pip check >/dev/null || { "$VENV/bin/python" -m pip check; die "the locked set is inconsistent"; }
  local out
  out=$(cd /tmp && "$VENV/bin/python" -c "import adademo_lerobot, lerobot, metaworld, gymnasium_robotics, mujoco" 2>&1) \
    || { echo "$out" >&2; die "the installed packages do not import; see the traceback above"; }
}

refresh_lock() {
  local tmp py; tmp=$(mktemp -d); py=$(find_python)
  trap 'rm -rf "$tmp"' RETURN
  echo "resolving pyproject.toml's ranges ([$EXTRAS]) in a fresh virtualenv ($tmp)"
  $py -m venv "$tmp/venv"
  pip_quiet "$tmp/venv/bin/python" -m pip install --quiet --disable-pip-version-check setuptools wheel
  pip_quiet "$tmp/venv/bin/python" -m pip install --quiet --disable-pip-version-check "${EDITABLES[@]}"
  {
    echo "# The whole resolved package set for adademo-lerobot (with extras [$EXTRAS]); setup.sh and CI install exactly this."
    echo "# Resolved $(date -u +%Y-%m-%d) on $(uname -m) Linux, $("$tmp/venv/bin/python" -V). Refresh deliberately:"
    echo "# bash setup.sh lock, then check the new set with bash setup.sh test and bash setup.sh quickstart (README)."
    "$tmp/venv/bin/python" -m pip freeze --all --exclude-editable | grep -v -E "$NOT_LOCKED"
  } > "$LOCK.new"
  if [ -f "$LOCK" ]; then diff <(grep -v '^#' "$LOCK") <(grep -v '^#' "$LOCK.new") || true; fi
  mv "$LOCK.new" "$LOCK"
  echo "wrote $LOCK ($(lock_lines | wc -l) packages); review the diff above, then run the tests and the quickstart"
}

# Two cores: keep torch from oversubscribing them beside env worker processes (docs/installation.md, "Threads on 2 cores").
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-2}"

case "${1:-}" in
  lock)
    refresh_lock
    ;;
  install)
    install_system_packages
    install_venv
    echo "installed: $VENV (activate with: source $VENV/bin/activate)"
    ;;
  test)
    shift
    install_system_packages
    install_venv
    echo "lint: ruff check and ruff format --check"
    "$VENV/bin/ruff" check . || die "ruff check found problems (ruff check --fix . fixes most)"
    "$VENV/bin/ruff" format --check . || die "files need formatting: run $VENV/bin/ruff format ."
    exec "$VENV/bin/python" -m pytest -q "$@"
    ;;
  quickstart)
    shift
    install_system_packages
    install_venv
    exec "$VENV/bin/adademo-run" --config_path=recipes/quickstart.yaml --run_dir=outputs/quickstart "$@"
    ;;
  *)
    echo "usage: bash setup.sh quickstart|test|install|lock [extra flags]" >&2
    exit 2
    ;;
esac
