#!/usr/bin/env bash
# The GPU measurements of docs/PERFORMANCE.md ("On a GPU"), in one go, logged to $LOG (default gpu_measure.log):
# the GPU's name, packs of 1, 16, 32 and 64 fast-network trials at 16 envs each (train/pack.py, one vmap'd program
# per network), bench_train.py's fast and paper networks at the paper's 16 envs and at 1,024, then a
# paper-scale Table 1 trial (sweeps/paper_table1.toml's settings, kappa 0.2 with annealing, seed 0) for
# TABLE1_SECONDS seconds, its training log copied to $RUN_LOG. The project must be installed (its commands are
# entry points): where nothing can be downloaded, `pip install --no-deps` its wheel and gymnasium's, pettingzoo's
# and farama-notifications' into a folder on PYTHONPATH. Usage: bash bench/gpu_measure.sh
set -u
LOG=${LOG:-gpu_measure.log}
RUN_LOG=${RUN_LOG:-gpu_table1_metrics.jsonl}
TABLE1_SECONDS=${TABLE1_SECONDS:-150}
export PYTHONUNBUFFERED=1
{
  date -u
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
  python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda)"
  timeout 200 python3 bench/bench_train.py --device cuda --setup fast --pack 1 16 32 64 --iterations 3
  timeout 200 python3 bench/bench_train.py --device cuda --setup fast paper --iterations 5
  timeout 150 python3 bench/bench_train.py --device cuda --setup fast --iterations 3 --num-envs 1024
  timeout 150 python3 bench/bench_train.py --device cuda --setup paper --iterations 2 --num-envs 256
  timeout 150 python3 bench/bench_train.py --device cuda --setup paper --iterations 2 --num-envs 1024
} 2>&1 | tee "$LOG"
{
  echo "paper-scale Table 1 trial (kappa 0.2, annealing 4M-10M, seed 0) for ${TABLE1_SECONDS} s"
  timeout "$TABLE1_SECONDS" python3 -m colorgrid_apps train --preset paper_symmetric --set total_steps=80000000 \
    --set leader.aux_coef=0.2 --set follower.aux_coef=0.2 --set schedule.penalty_start=4000000 \
    --set schedule.penalty_end=10000000 --set eval_every=0 --set save_every=100000 --set device=cuda --set seed=0 \
    --out /tmp/table1_gpu --no-progress
  echo "exit $?"
  cp /tmp/table1_gpu/metrics.jsonl "$RUN_LOG" 2>/dev/null
  tail -n 2 "$RUN_LOG" 2>/dev/null
} 2>&1 | tee -a "$LOG"
