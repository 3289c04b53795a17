# Sourced by scripts/run and scripts/test: make sure .venv exists, is active, and has Curio
# installed (install_curio EXTRAS). Installing happens only when pyproject.toml changed since
# the last install, and without the network when every dependency is already in the venv.
set -euo pipefail
PY=${PYTHON:-python3}
as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }
apt_install() {
  if command -v apt-get >/dev/null 2>&1; then
    as_root apt-get update -qq && as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@"
  else
    echo "please install: $*" >&2; return 1
  fi
}
if [ ! -x .venv/bin/python ]; then
  if ! "$PY" -m venv .venv 2>/dev/null; then
    rm -rf .venv
    ver=$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')
    apt_install "python${ver}-venv" || apt_install python3-venv
    "$PY" -m venv .venv
  fi
  # A build backend in the venv lets later installs work offline (--no-build-isolation).
  .venv/bin/python -m pip install -q --upgrade pip 'setuptools>=77' wheel
fi
export PATH="$PWD/.venv/bin:$PATH"

# install_curio [EXTRAS]: pip install -e ".[EXTRAS]" unless already done for this pyproject.toml.
install_curio() {
  local extras=${1:-} stamp want
  stamp=".venv/.curio-installed${extras:+-$extras}"
  want=$(sha256sum pyproject.toml | cut -c1-16)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && python -c 'import curio' 2>/dev/null; then
    return 0
  fi
  local spec=".${extras:+[$extras]}"
  echo "installing Curio${extras:+ with [$extras]} into .venv ..." >&2
  local log=.venv/install.log
  if ! PYTHONWARNINGS=ignore python -m pip install -q --no-index --no-build-isolation \
      -e "$spec" >"$log" 2>&1; then
    # Something is missing: fetch it (needs the network). Quiet unless it fails.
    if ! PYTHONWARNINGS=ignore python -m pip install -q -e "$spec" >"$log" 2>&1; then
      cat "$log" >&2
      echo "installing Curio failed (the log above is in $log)" >&2
      return 1
    fi
  fi
  echo "$want" > "$stamp"
}
