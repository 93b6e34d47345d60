#!/usr/bin/env bash
# One entry point for a fresh machine: creates the project environment (.venv, Python 3.12)
# if it is missing, installs fempm into it, then runs the main job or the tests.
#
#   ./run.sh demo [flags]         the dam break of the seed (results/dambreak/)
#   ./run.sh test [pytest flags]     the whole test suite, its files shared by up to 4 processes
#                                    (pytest-xdist; -n 0: in one), the mpi-marked tests again on 2 ranks
set -euo pipefail
cd "$(dirname "$0")"

find_python312() {
  local candidates=(python3.12)
  if command -v pyenv >/dev/null 2>&1; then
    candidates+=("$(pyenv root)"/versions/3.12*/bin/python3.12)
  fi
  candidates+=("$HOME"/.pyenv/versions/3.12*/bin/python3.12 /usr/local/bin/python3.12 /usr/bin/python3.12)
  for py in "${candidates[@]}"; do
    if "$py" -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1; then
      echo "$py"; return 0
    fi
  done
  echo "run.sh: no working python3.12 found (tried: ${candidates[*]})" >&2
  return 1
}

setup() {
  if [[ ! -x .venv/bin/python ]]; then
    local py; py=$(find_python312)
    echo "run.sh: creating .venv with $py"
    "$py" -m venv .venv
    .venv/bin/python -m pip install --quiet --upgrade pip
  fi
  # reinstall when pyproject.toml or the pinned versions (constraints.txt) changed since the last install
  if [[ ! -f .venv/.fempm-installed || pyproject.toml -nt .venv/.fempm-installed || constraints.txt -nt .venv/.fempm-installed ]]; then
    echo "run.sh: installing fempm and its dependencies into .venv (the versions of constraints.txt)"
    .venv/bin/python -m pip install --quiet -c constraints.txt -e ".[test]"
    touch .venv/.fempm-installed
  fi
  export PATH="$PWD/.venv/bin:$PATH"
}

job=${1:-}
shift || true
case "$job" in
  demo)     setup; exec python demos/dambreak.py "$@" ;;
  test)     setup
            cores=$(nproc 2>/dev/null || echo 1)
            exec python -m pytest -n "$(( cores < 4 ? cores : 4 ))" --dist loadfile "$@" ;;
  *) echo "usage: ./run.sh demo [flags] | ./run.sh test [pytest flags]" >&2; exit 2 ;;
esac
