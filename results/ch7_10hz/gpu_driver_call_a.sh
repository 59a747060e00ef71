#!/bin/bash
# Session 13, call A: chapter-7 table at 10 Hz on the 3-link (ILfO, IL, RLfO; 10 expert episodes),
# MAHALO learning curves, and the ILfO cell with 100 expert episodes.
# The grep starts from session 12's results.jsonl without its MAHALO row (rerun here with --curve).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; O=$OUT/x; mkdir -p $O $W
grep -v '"learner": "MAHALO"' results/ch7_10hz/results.jsonl > $W/results.jsonl
B="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 50000 --actor nn_residual --envs three_link/env3 --out $W"
C="$B --expert-scale 10"; H="$B --expert-scale 100"
$C --stage collect > $O/collect10.log 2>&1; $H --stage collect > $O/collect100.log 2>&1
nvidia-smi --query-gpu=name --format=csv > $O/gpu.txt
T="timeout 530"
$T $C --stage train --scenarios ILfO --learners MAHALO --curve --chunk 5000 > $O/t_ilfo_mahalo.log 2>&1 &
$T $C --stage train --scenarios ILfO --learners AP > $O/t_ilfo_ap.log 2>&1 &
for l in MAHALO RP AP UDS ATAC Oracle; do $T $C --stage train --scenarios IL --learners $l > $O/t_il_$l.log 2>&1 & done
for l in MAHALO RP AP Oracle; do $T $C --stage train --scenarios RLfO --learners $l > $O/t_rlfo_$l.log 2>&1 & done
$T $C --stage train --scenarios IL RLfO --learners BC BCO > $O/t_bc.log 2>&1 &
$T $H --stage train --scenarios ILfO --learners MAHALO --curve --chunk 5000 > $O/t100_mahalo.log 2>&1 &
$T $H --stage train --scenarios ILfO --learners RP AP BCO > $O/t100_rest.log 2>&1 &
wait
$C --stage table --scenarios ILfO IL RLfO > $O/table10.log 2>&1
$H --stage table --scenarios ILfO > $O/table100.log 2>&1
cp $O/*.log $O/gpu.txt $W/; cd /tmp && tar czf $OUT/ch7_10hz_a.tgz --exclude='ch7_10hz/data' ch7_10hz
grep -h "\[train\]\|\[curve\]" $O/t*.log; tail -12 $O/table10.log; tail -5 $O/table100.log
