#!/bin/bash
# Session 13, call F: Franka ILfO at 10 Hz (100 expert episodes) for 150 k steps with learning
# curves: do Oracle and MAHALO pass BC with three times the steps?
END=$(( $(date +%s) + 450 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz_long; O=$OUT/x; mkdir -p $O $W
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 150000 --chunk 50000 --curve --actor nn_residual --envs franka --out $W --expert-scale 100 --scenarios ILfO"
$H --stage collect > $O/collect.log 2>&1
T="timeout $(( END - $(date +%s) ))"
for l in Oracle MAHALO BC; do $T $H --stage train --learners $l > $O/t_$l.log 2>&1 & done
wait
$H --stage table > $O/table.log 2>&1
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_10hz_long.tgz --exclude='ch7_10hz_long/data' ch7_10hz_long
grep -h "\[train\]\|\[curve\]\|steps," $O/t*.log | tail -30
