#!/bin/bash
# ch8 on D4RL-style data: medium-replay from the snapshots of a plain-NN PPO run on env3
# (collision-prone), collision terminals removed (thesis footnote 4); ATAC/PSPI x 4 rewards and BC
# on medium-replay-cut vs -full, 60k steps (30k BC warm start), scaled actor rate, NN-RESIDUAL.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:. || exit 1
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
T0=$SECONDS; R=/tmp/nn_env3_run; D=/tmp/ch8ppo; mkdir -p $D /tmp/logs
python scripts/train.py --env three_link/env3 --policy nn --preset thesis --iterations 150 \
  --log-every 10 --checkpoint-every 10 --keep-checkpoints 0 --out $R --no-progress > /tmp/logs/ppo.log 2>&1
echo "ppo rc=$? wall $((SECONDS-T0)) s"; tail -4 /tmp/logs/ppo.log
tar czf $OUT/nn_env3_run.tgz -C /tmp nn_env3_run
COMMON="--preset gpu --actor nn_residual --actor-rate scaled --recipes medium-replay --ppo-run $R --terminals remove --no-safety --steps 60000 --warmstart 0.5 --chunk 15000 --curve --out $D"
python scripts/reproduce_ch8.py $COMMON --stage collect > /tmp/logs/collect.log 2>&1
echo "collect rc=$? wall $((SECONDS-T0)) s"; grep "\[collect\]" /tmp/logs/collect.log
P=()
for job in medium-replay-cut:ATAC medium-replay-full:ATAC medium-replay-cut:PSPI medium-replay-full:PSPI medium-replay-cut,medium-replay-full:BC; do
  ds=${job%%:*}; lrn=${job##*:}
  timeout $((575 - SECONDS + T0)) python scripts/reproduce_ch8.py $COMMON --stage train --datasets ${ds//,/ } --learners $lrn > /tmp/logs/train_${ds//,/_}_$lrn.log 2>&1 &
  P+=($!)
done
( while sleep 20; do cp $D/results.jsonl $OUT/results_partial.jsonl 2>/dev/null; done ) &
WATCH=$!
wait "${P[@]}"; kill $WATCH
echo "train done wall $((SECONDS-T0)) s"
cp $D/results.jsonl $OUT/results.jsonl; rm -f $OUT/*_partial.jsonl
timeout $((595 - SECONDS + T0)) python scripts/reproduce_ch8.py $COMMON --stage figures > /tmp/logs/figures.log 2>&1
echo "figures rc=$? total wall $((SECONDS-T0)) s"
grep -h "\[train\]\|\[time\]" /tmp/logs/train_*.log
tar czf $OUT/ch8ppo.tgz --exclude=data -C /tmp ch8ppo logs
