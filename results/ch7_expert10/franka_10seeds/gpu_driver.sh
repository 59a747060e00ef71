#!/bin/bash
# ch7 Franka ILfO with 10 expert episodes at 10 seeds: MAHALO, BC, BCO (the ILfO comparison of issue 6 item 2).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:. || exit 1
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
LIMIT=${1:-560}
T0=$SECONDS
mkdir -p /tmp/logs
CF="--preset gpu --actor nn_residual --actor-rate published --warmstart 0.75 --steps 40000 --chunk 40000 --expert-scale 10 --envs franka --seeds 10 --out /tmp/c7s"
python scripts/reproduce_ch7.py $CF --stage collect > /tmp/logs/collect_f.log 2>&1
echo "collect wall $((SECONDS-T0)) s"
i=0
for lrn in MAHALO BCO BC; do
  timeout $((LIMIT - SECONDS + T0)) python scripts/reproduce_ch7.py $CF --stage train --scenarios ILfO --learners $lrn > /tmp/logs/w$i.log 2>&1 &
  i=$((i+1))
done
wait
echo "all wall $((SECONDS-T0)) s"
python scripts/reproduce_ch7.py $CF --stage table 2>&1 | tail -4
grep -h "\[train\]" /tmp/logs/w*.log | sort
rm -rf /tmp/c7s/data
tar czf $OUT/ch7s.tgz -C /tmp c7s logs
