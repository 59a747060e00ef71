#!/bin/bash
# Session 12: chapter-7 ILfO on the 3-link at a 10 Hz control step (10 expert episodes).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; O=$OUT/x; mkdir -p $O
C="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --expert-scale 10 --steps 50000 --chunk 50000 --actor nn_residual --envs three_link/env3 --scenarios ILfO --out $W"
$C --stage collect > $O/collect.log 2>&1
for l in MAHALO BC BCO Oracle RP; do timeout 470 $C --stage train --learners $l > $O/train_$l.log 2>&1 & done
wait
$C --stage table --learners MAHALO RP BCO BC Oracle > $O/table.log 2>&1
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_10hz.tgz --exclude='ch7_10hz/data' ch7_10hz
grep -h "\[train\]" $O/train_*.log; cat $O/table.log | tail -8
