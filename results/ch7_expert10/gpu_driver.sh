#!/bin/bash
# ch7 ILfO rows with a small expert set (10 episodes, the D4RL protocol's size), 3-link (20k steps) and Franka (40k, warm 0.75).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:. || exit 1
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
LIMIT=${1:-560}; NE=${2:-10}; SCEN=${3:-ILfO}
T0=$SECONDS
mkdir -p /tmp/logs
CE="--preset gpu --actor nn_residual --actor-rate published --warmstart 0.1 --steps 20000 --chunk 20000 --expert-scale $NE --envs three_link/env3 --out /tmp/c7e"
CF="--preset gpu --actor nn_residual --actor-rate published --warmstart 0.75 --steps 40000 --chunk 40000 --expert-scale $NE --envs franka --out /tmp/c7f"
python scripts/reproduce_ch7.py $CE --stage collect > /tmp/logs/collect_e.log 2>&1 &
python scripts/reproduce_ch7.py $CF --stage collect > /tmp/logs/collect_f.log 2>&1 &
wait
echo "collect wall $((SECONDS-T0)) s"; cat /tmp/logs/collect_*.log | grep collect
TASKS=("E|MAHALO RP" "E|AP UDS" "E|ATAC Oracle" "E|BCO BC" "F|MAHALO" "F|RP" "F|AP" "F|UDS" "F|ATAC" "F|Oracle" "F|BCO BC")
i=0
for t in "${TASKS[@]}"; do
  IFS='|' read -r e lrn <<< "$t"
  if [ $e = E ]; then C=$CE; else C=$CF; fi
  timeout $((LIMIT - SECONDS + T0)) python scripts/reproduce_ch7.py $C --stage train --scenarios $SCEN --learners $lrn > /tmp/logs/w$i.log 2>&1 &
  i=$((i+1))
done
( while sleep 30; do cp /tmp/c7e/results.jsonl $OUT/e_partial.jsonl 2>/dev/null; cp /tmp/c7f/results.jsonl $OUT/f_partial.jsonl 2>/dev/null; done ) &
WATCH=$!
wait $(jobs -p | grep -v $WATCH) 2>/dev/null
kill $WATCH
echo "all wall $((SECONDS-T0)) s"
rm -f $OUT/*_partial.jsonl
python scripts/reproduce_ch7.py $CE --stage table 2>&1 | tail -5
python scripts/reproduce_ch7.py $CF --stage table 2>&1 | tail -5
grep -h "\[train\]" /tmp/logs/w*.log | sort
rm -rf /tmp/c7e/data /tmp/c7f/data
tar czf $OUT/ch7e.tgz -C /tmp c7e c7f logs
