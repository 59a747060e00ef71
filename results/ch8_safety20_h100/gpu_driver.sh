#!/bin/bash
# ch8 safety from filtered data (§8.4.2) with 20 seeds x 128 evaluation episodes: the session-7
# setting (NN-RESIDUAL actor, published actor rate, 30k steps, 10% warm start), true reward only,
# ATAC / PSPI / BC on mixed-full and mixed-full-filtered.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:. || exit 1
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
T0=$SECONDS; D=/tmp/ch8s; mkdir -p $D /tmp/logs
COMMON="--preset gpu --actor nn_residual --recipes mixed --steps 30000 --seeds 20 --eval-episodes 128 --rewards original --out $D"
python scripts/reproduce_ch8.py $COMMON --stage collect > /tmp/logs/collect.log 2>&1
echo "collect rc=$? wall $((SECONDS-T0)) s"; grep "\[collect\]" /tmp/logs/collect.log
P=()
for job in mixed-full:ATAC mixed-full-filtered:ATAC mixed-full:PSPI mixed-full-filtered:PSPI mixed-full,mixed-full-filtered:BC; do
  ds=${job%%:*}; lrn=${job##*:}
  timeout $((570 - SECONDS + T0)) python scripts/reproduce_ch8.py $COMMON --stage train --datasets ${ds//,/ } --learners $lrn > /tmp/logs/train_${ds//,/_}_$lrn.log 2>&1 &
  P+=($!)
done
( while sleep 20; do cp $D/results.jsonl $OUT/results_partial.jsonl 2>/dev/null; done ) &
WATCH=$!
wait "${P[@]}"; kill $WATCH
echo "train done wall $((SECONDS-T0)) s"
cp $D/results.jsonl $OUT/results.jsonl; rm -f $OUT/*_partial.jsonl
timeout $((595 - SECONDS + T0)) python scripts/reproduce_ch8.py $COMMON --stage figures > /tmp/logs/figures.log 2>&1
echo "figures rc=$? total wall $((SECONDS-T0)) s"
cat $D/safety.md 2>/dev/null
grep -h "\[train\]\|\[time\]" /tmp/logs/train_*.log
tar czf $OUT/ch8s.tgz --exclude=data -C /tmp ch8s logs
