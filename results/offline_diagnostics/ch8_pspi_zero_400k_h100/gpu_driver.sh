#!/bin/bash
# ch8: PSPI with the zero reward on medium-replay-full / -goal, 400k steps (40k warm start), curves every 50k.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:. || exit 1
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
LIMIT=${1:-560}; STEPS=${2:-400000}; CHUNK=${3:-50000}
D=/tmp/ch8pspi; mkdir -p $D /tmp/logs
T0=$SECONDS
COMMON="--preset gpu --actor nn_residual --recipes medium-replay --goal-deadline 350 --learners PSPI --rewards zero --no-safety --steps $STEPS --chunk $CHUNK --curve --out $D"
python scripts/reproduce_ch8.py $COMMON --stage collect > /tmp/logs/collect.log 2>&1
echo "collect rc=$? wall $((SECONDS-T0)) s"
P=()
for ds in medium-replay-full medium-replay-goal; do
  timeout $((LIMIT - SECONDS + T0)) python scripts/reproduce_ch8.py $COMMON --stage train --datasets $ds > /tmp/logs/train_$ds.log 2>&1 &
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
grep -h "steps,\|\[curve\]\|\[time\]\|\[train\]" /tmp/logs/train_*.log
tar czf $OUT/ch8pspi.tgz --exclude=data -C /tmp ch8pspi logs
