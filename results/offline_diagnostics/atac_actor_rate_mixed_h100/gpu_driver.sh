#!/bin/bash
# Session-12 diagnostic driver: ATAC (true reward) vs BC on 3-link env3 `mixed` at three actor rates.
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
O=$OUT/atac_improve; mkdir -p $O
S=80000; W=8000; C=16000
python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program bc --steps 1000 --chunk 1000 --seeds 1 --out /tmp/warm.jsonl > $O/collect.log 2>&1
python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program bc --steps $S --chunk $C --out $O/results.jsonl > $O/bc.log 2>&1 &
python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program topbc --steps $S --chunk $C --out $O/results.jsonl > $O/topbc.log 2>&1 &
for lr in 5e-7 5e-5; do  # 5e-6 ran in the first call (same settings)
  python3 results/offline_diagnostics/atac_actor_rate_mixed_h100/atac_improve.py --program atac --actor-lr $lr --betas 1 16 --steps $S --warm $W --chunk $C --out $O/results.jsonl > $O/atac_$lr.log 2>&1 &
done
wait
nvidia-smi --query-gpu=name --format=csv > $O/gpu.txt
for f in $O/*.log; do tail -n 3 $f; done
