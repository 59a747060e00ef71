#!/bin/bash
# Session 13, call C: chapter-7 table at 10 Hz on the Franka with 100 expert episodes: ILfO, RLfO, part of IL.
# .exp/results_*.jsonl is the results.jsonl that the previous calls returned (carried with the driver).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; O=$OUT/x; mkdir -p $O $W
cp .exp/results_b.jsonl $W/results.jsonl
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 50000 --actor nn_residual --envs franka --out $W --expert-scale 100"
$H --stage collect > $O/collect_franka.log 2>&1
T="timeout 540"
for l in MAHALO RP AP Oracle; do $T $H --stage train --scenarios ILfO --learners $l > $O/t_ilfo_$l.log 2>&1 & done
for l in MAHALO RP AP; do $T $H --stage train --scenarios RLfO --learners $l > $O/t_rlfo_$l.log 2>&1 & done
for l in MAHALO RP AP Oracle; do $T $H --stage train --scenarios IL --learners $l > $O/t_il_$l.log 2>&1 & done
$T $H --stage train --scenarios ILfO RLfO IL --learners BC BCO > $O/t_bc.log 2>&1 &
wait
$H --stage table --scenarios ILfO IL RLfO > $O/table100.log 2>&1
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_10hz_c.tgz --exclude='ch7_10hz/data' ch7_10hz
grep -h "\[collect\]" $O/collect_franka.log; grep -h "\[train\]" $O/t*.log; tail -8 $O/table100.log
