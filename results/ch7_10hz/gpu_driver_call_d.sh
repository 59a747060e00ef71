#!/bin/bash
# Session 13, call D: chapter-7 table at 10 Hz on the 3-link with 100 expert episodes: RL-expert, RL-sample.
# .exp/results_*.jsonl is the results.jsonl that the previous calls returned (carried with the driver).
END=$(( $(date +%s) + 555 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; O=$OUT/x; mkdir -p $O $W
cp .exp/results_b.jsonl $W/results.jsonl
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 50000 --actor nn_residual --envs three_link/env3 --out $W --expert-scale 100"
$H --stage collect > $O/collect100.log 2>&1
T="timeout $(( END - $(date +%s) ))"
for s in RL-expert RL-sample; do for l in MAHALO RP AP UDS ATAC Oracle; do $T $H --stage train --scenarios $s --learners $l > $O/t_${s}_$l.log 2>&1 & done; done
$T $H --stage train --scenarios RL-expert RL-sample --learners BC BCO > $O/t_bc.log 2>&1 &
wait
$H --stage table > $O/table100.log 2>&1
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_10hz_d.tgz --exclude='ch7_10hz/data' ch7_10hz
grep -h "\[train\]" $O/t*.log; tail -10 $O/table100.log
