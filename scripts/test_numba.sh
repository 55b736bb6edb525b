#!/usr/bin/env bash
# The test suite with the oldest and the newest Numba that pyproject.toml declares, each in a venv of its own
# (.venv-numba-oldest, .venv-numba-newest; NumPy pinned to what that Numba supports), and once more with kernels
# compiled for a generic x86-64/arm64 CPU instead of this machine's (NUMBA_CPU_NAME=generic), with the BLAS and
# NumPy's vectorised loops of another processor where they can be chosen (OPENBLAS_CORETYPE, NPY_DISABLE_CPU_FEATURES).
# Each runs `make test`'s selection; MARKS="not heavy" adds the `long` tier (about 15 minutes more each).
# Usage: scripts/test_numba.sh [oldest|newest|generic ...]   (default: all three)
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
MARKS=${MARKS:-not heavy and not long}
# the bounds of pyproject.toml's numba requirement, and the NumPy each supports
OLDEST="numba==0.59.1 numpy==1.26.4"
NEWEST="numba==0.68.1"
grep -q '"numba>=0.59,<0.69"' pyproject.toml || { echo "test_numba.sh: update OLDEST/NEWEST to pyproject.toml's numba bounds" >&2; exit 2; }

env_for() {   # name, pins -> the venv's python
    local venv=".venv-numba-$1"
    if [ ! -f "$venv/.installed" ] || [ "$(cat "$venv/.installed")" != "$2" ]; then
        rm -rf "$venv"
        "$PYTHON" -m venv "$venv"
        "$venv/bin/python" -m pip install --quiet --upgrade pip
        # shellcheck disable=SC2086
        "$venv/bin/python" -m pip install --quiet -e '.[dev]' $2
        echo "$2" > "$venv/.installed"
    fi
    echo "$venv/bin/python"
}

run() {   # label, python, extra env
    local label=$1 py=$2; shift 2
    echo "== $label: $("$py" -c 'import numba, numpy; print("numba", numba.__version__, "numpy", numpy.__version__)') $*"
    # a cache folder of its own: kernels compiled for another CPU or by another Numba are kept apart
    env "$@" NUMBA_CACHE_DIR="$PWD/.cache-numba-$label" "$py" -m pytest -q -n 2 -m "$MARKS" -p no:cacheprovider tests
}

for what in "${@:-oldest newest generic}"; do
    for w in $what; do
        case $w in
            oldest) run oldest "$(env_for oldest "$OLDEST")" ;;
            newest) run newest "$(env_for newest "$NEWEST")" ;;
            generic)
                other=()
                if [ "$(uname -m)" = x86_64 ]; then
                    # the BLAS kernel of an AVX-512 Xeon, and NumPy's loops without AVX-512
                    other=(OPENBLAS_CORETYPE=SkylakeX "NPY_DISABLE_CPU_FEATURES=X86_V4 AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR")
                fi
                run generic "$(env_for newest "$NEWEST")" NUMBA_CPU_NAME=generic "${other[@]}" ;;
            *) echo "test_numba.sh: unknown '$w' (oldest, newest, generic)" >&2; exit 2 ;;
        esac
    done
done
