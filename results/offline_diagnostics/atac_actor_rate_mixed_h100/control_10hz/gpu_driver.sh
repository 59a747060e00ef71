#!/bin/bash
# Session-12 causal check of the action-gap reading: the same comparison with 10 Hz control
# (24 physics substeps per control step, horizon 75 = 7.5 s), mixed x400 (1,600 scenes).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
O=$OUT/hz10; mkdir -p $O
S=80000; W=8000; C=16000; D="--substeps 24 --scale 400 --data /tmp/mixed10hz.npz"
P=results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py
python3 $P --program bc $D --steps 1000 --chunk 1000 --seeds 1 --out /tmp/warm.jsonl > $O/collect.log 2>&1
python3 $P --program bc $D --steps $S --chunk $C --out $O/results.jsonl > $O/bc.log 2>&1 &
python3 $P --program topbc $D --steps $S --chunk $C --out $O/results.jsonl > $O/topbc.log 2>&1 &
python3 $P --program bc $D --actor mlp --steps $S --chunk $C --out $O/results.jsonl > $O/bc_mlp.log 2>&1 &
for lr in 5e-7 5e-6 5e-5; do
  python3 $P --program atac $D --actor-lr $lr --betas 1 16 --steps $S --warm $W --chunk $C --out $O/results.jsonl > $O/atac_$lr.log 2>&1 &
done
python3 $P --program atac $D --actor mlp --actor-lr 5e-6 --betas 1 16 --steps $S --warm $W --chunk $C --out $O/results.jsonl > $O/atac_mlp_5e-6.log 2>&1 &
wait
for f in $O/*.log; do echo $f; grep -v warp $f | tail -n 6; done
