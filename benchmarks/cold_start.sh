#!/bin/bash
# The cold-start measurement of docs/results/cold-start.md: `softshadows compare bunny` twice, each
# from an empty Numba cache, wall and CPU time from /usr/bin/time -v.
#   benchmarks/cold_start.sh [SRC_DIR (default: ./src)] [TAG]
SRC=${1:-$(pwd)/src}; TAG=${2:-cold}; PY=${PYTHON:-python}
for i in 1 2; do
  rm -rf /tmp/nbc_$TAG
  NUMBA_CACHE_DIR=/tmp/nbc_$TAG PYTHONPATH=$SRC /usr/bin/time -v $PY -m softshadows compare bunny -o /tmp/cmp_$TAG \
    > /tmp/cold_${TAG}_$i.out 2> /tmp/cold_${TAG}_$i.err
  echo "$TAG run $i: $(grep -E 'Elapsed|User time|System time' /tmp/cold_${TAG}_$i.err | tr '\n' ' ')"
done
