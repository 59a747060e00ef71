#!/bin/bash
# Session-12 diagnostic: the same comparison on `mixed` with 10x the scenes (scale 1000 = 4000 episodes).
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
O=$OUT/scale1000; mkdir -p $O
S=80000; W=8000; C=16000; D="--scale 1000 --data /tmp/mixed1000.npz"
python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program bc $D --steps 1000 --chunk 1000 --seeds 1 --out /tmp/warm.jsonl > $O/collect.log 2>&1
for actor in mlp nn_residual; do
  python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program bc $D --actor $actor --steps $S --chunk $C --out $O/results.jsonl > $O/bc_$actor.log 2>&1 &
  python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program atac $D --actor $actor --actor-lr 5e-7 --betas 16 --steps $S --warm $W --chunk $C --out $O/results.jsonl > $O/atac_$actor.log 2>&1 &
done
python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program topbc $D --actor mlp --steps $S --chunk $C --out $O/results.jsonl > $O/topbc_mlp.log 2>&1 &
wait
for f in $O/*.log; do echo $f; grep -v warp $f | tail -n 6; done
