#!/usr/bin/env bash
# The test suite as `make test` runs it, on a 2-core machine:
#
#   background, at nice 10: pytest on two workers (pytest-xdist) for every test but the
#     realtime ones, and beside them the documentation build (warnings are errors). Its
#     gallery runs a served plant in real time and waits most of its 3 minutes, so it
#     costs the workers about a third of a core while it runs; started after the
#     realtime tests (as it was until 2026-11-29), its 4 minutes of wall time followed
#     their 11.
#   foreground, at normal priority: the realtime tests (wall-clock loops against a served
#     plant), one at a time, so that the niced jobs never delay a loop period.
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
workers_job=$!
(
    nice -n 10 "${MAKE:-make}" --no-print-directory docs > out/docs.log 2>&1
    echo $? > out/docs.rc
) &
docs_job=$!
echo "== realtime tests (the rest of the suite and the docs build run meanwhile, niced) =="
start=$(date +%s)
"$py" -m pytest -q -p no:cacheprovider -m realtime
realtime=$?
echo "(realtime tests: $(( $(date +%s) - start )) s of wall time)"
wait "$docs_job"
echo "== documentation build (done after $(( $(date +%s) - start )) s) =="
cat out/docs.log
wait "$workers_job"
echo "== the rest of the suite (two workers; done after $(( $(date +%s) - start )) s) =="
cat out/test-workers.log
workers=$(cat out/test-workers.rc)
docs=$(cat out/docs.rc)
echo "realtime tests: exit $realtime; the rest: exit $workers; docs: exit $docs"
[ "$realtime" -eq 0 ] && [ "$workers" -eq 0 ] && [ "$docs" -eq 0 ]
