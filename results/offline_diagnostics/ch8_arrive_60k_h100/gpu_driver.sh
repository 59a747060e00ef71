#!/bin/bash
# ch8 arrival-terminal data (-arrive): ATAC/PSPI/BC on medium-replay-arrive, same settings as the
# session-10 -goal/-full run (whose results.jsonl seeds the folder, so the table has all three).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:. || exit 1
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
LIMIT=${1:-570}; shift; JOBS=("$@")   # JOBS: dataset:learner pairs, e.g. medium-replay-goal:ATAC
D=/tmp/ch8goal; mkdir -p $D /tmp/logs
cp results/offline_diagnostics/ch8_goal_60k_h100/results.jsonl $D/results.jsonl
T0=$SECONDS
COMMON="--preset gpu --actor nn_residual --actor-rate scaled --recipes medium-replay --goal-deadline 350 --no-safety --steps 60000 --warmstart 0.5 --chunk 15000 --curve --out $D"
python scripts/reproduce_ch8.py $COMMON --stage collect > /tmp/logs/collect.log 2>&1
echo "collect rc=$? wall $((SECONDS-T0)) s"
P=()
for job in "${JOBS[@]}"; do
  ds=${job%%:*}; lrn=${job##*:}
  timeout $((LIMIT - SECONDS + T0)) python scripts/reproduce_ch8.py $COMMON --stage train --datasets ${ds//,/ } --learners $lrn > /tmp/logs/train_${ds//,/_}_$lrn.log 2>&1 &
  P+=($!)
done
( while sleep 20; do cp /tmp/logs/train_*.log $OUT/ 2>/dev/null; cp $D/results.jsonl $OUT/results_partial.jsonl 2>/dev/null; done ) &
WATCH=$!
wait "${P[@]}"
kill $WATCH
echo "train done wall $((SECONDS-T0)) s"
cp $D/results.jsonl $OUT/results.jsonl; rm -f $OUT/*_partial.jsonl
python scripts/reproduce_ch8.py $COMMON --stage figures > /tmp/logs/figures.log 2>&1
echo "figures rc=$? total wall $((SECONDS-T0)) s"
grep -h "\[curve\]\|\[time\]\|\[train\]" /tmp/logs/train_*.log
tar czf $OUT/ch8goal.tgz --exclude=data -C /tmp ch8goal logs
