#!/usr/bin/env bash
# The test suite as `make test` runs it, on a 2-core machine in about 10 minutes:
#
#   background, at nice 10: pytest on two workers (pytest-xdist) for every test but the
#     realtime ones;
#   foreground, at normal priority: the realtime tests (wall-clock loops against a served
#     plant), one at a time, so that the niced workers never delay a loop period; then the
#     documentation build (warnings are errors). Its gallery runs a served plant in real
#     time and waits most of its 3 minutes (a third of a core), so it overlaps the
#     workers' end instead of following it.
#
# All three logs are printed; the exit code is 0 only if all three parts passed.
# Usage: tools/run_suite.sh PYTHON   (from the project root; `make test` calls it)
set -u
py=$1
mkdir -p out
(
    nice -n 10 "$py" -m pytest -q -p no:cacheprovider -n 2 --dist loadfile --durations=30 -m "not realtime" \
        > out/test-workers.log 2>&1
    echo $? > out/test-workers.rc
) &
background=$!
echo "== realtime tests (the rest of the suite runs meanwhile, niced) =="
"$py" -m pytest -q -p no:cacheprovider -m realtime
realtime=$?
"${MAKE:-make}" --no-print-directory docs > out/docs.log 2>&1
docs=$?
wait "$background"
echo "== the rest of the suite (two workers) =="
cat out/test-workers.log
echo "== documentation build =="
cat out/docs.log
workers=$(cat out/test-workers.rc)
echo "realtime tests: exit $realtime; the rest: exit $workers; docs: exit $docs"
[ "$realtime" -eq 0 ] && [ "$workers" -eq 0 ] && [ "$docs" -eq 0 ]
