# Sourced by scripts/demo and scripts/test: create .venv and install the project into it once.
# Re-installs only when pyproject.toml changed since the last install.
set -euo pipefail
repo_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${RIG_VENV:-$repo_root/.venv}"
python_bin="${PYTHON:-python3}"
stamp="$venv/.installed-pyproject"
if [ ! -x "$venv/bin/python" ]; then
    echo "first run: creating $venv and installing the project and its dependencies (about 1-2 minutes," \
         "needs the network once; later runs start at once)" >&2
    "$python_bin" -m venv "$venv"
fi
if [ ! -f "$stamp" ] || ! cmp -s "$repo_root/pyproject.toml" "$stamp"; then
    echo "installing the project into $venv (pyproject.toml is new or changed) ..." >&2
    "$venv/bin/python" -m pip install --quiet --upgrade pip >/dev/null
    "$venv/bin/python" -m pip install --quiet -e "$repo_root[test]"
    cp "$repo_root/pyproject.toml" "$stamp"
    echo "installed; starting" >&2
fi
export PATH="$venv/bin:$PATH"
