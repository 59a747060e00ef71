#!/bin/bash
# Session 13, call E: chapter-7 table at 10 Hz on the Franka with 100 expert episodes: ILfO and RLfO.
# .exp/results_*.jsonl is the results.jsonl that the previous calls returned (carried with the driver).
END=$(( $(date +%s) + 555 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; O=$OUT/x; mkdir -p $O $W
cp .exp/results_d.jsonl $W/results.jsonl
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 50000 --actor nn_residual --envs franka --out $W --expert-scale 100"
$H --stage collect > $O/collect100.log 2>&1
T="timeout $(( END - $(date +%s) ))"
for l in MAHALO RP AP Oracle; do $T $H --stage train --scenarios ILfO --learners $l > $O/t_ilfo_$l.log 2>&1 & done
for l in MAHALO RP AP; do $T $H --stage train --scenarios RLfO --learners $l > $O/t_rlfo_$l.log 2>&1 & done
$T $H --stage train --scenarios ILfO RLfO --learners BC BCO > $O/t_bc.log 2>&1 &
wait
$H --stage table --scenarios ILfO RLfO > $O/table100.log 2>&1
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_10hz_e.tgz --exclude='ch7_10hz/data' ch7_10hz
grep -h "\[train\]" $O/t*.log; tail -10 $O/table100.log
