#!/usr/bin/env bash
# Advance sweeps on a machine without Ray (a lent GPU machine's CPU cores, say) for SECONDS, then pack each
# sweep's folder (training logs and each trial's latest checkpoint) into $OUT/<name>.<k>.tgz (six trials each) to carry back. Each
# FILE:N runs N of the file's trials at a time (train.sweep.local, as `colorgrid sweep run FILE --local N`).
# Back here: tar xzf <name>.<k>.tgz -C runs/sweeps, then continue with `colorgrid sweep run FILE --local N`, or
# keep the finished trials with `colorgrid sweep publish runs/sweeps/<name>`. The project must be importable
# (PYTHONPATH), as bench/gpu_measure.sh says.
# Usage: bash bench/lent_sweeps.sh SECONDS sweeps/paper_table1_eighth.toml:12 sweeps/assistant_recipe.toml:4
set -u
seconds=$1; shift
out=${OUT:-.}
export PYTHONUNBUFFERED=1
{ date -u; echo "cores: $(nproc)"; lscpu | grep -m1 'Model name'; } 2>&1 | tee "$out/lent_sweeps.log"
names=()
for arg in "$@"; do
  file=${arg%:*}; n=${arg##*:}; name=$(basename "$file" .toml); names+=("$name")
  python3 -c 'import sys
from train.sweep.local import run_local
from train.sweep.spec import load_sweep
sys.exit(run_local(load_sweep(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])))' "$file" "$n" "$seconds" \
    > "$out/$name.log" 2>&1 &
done
wait
for name in "${names[@]}"; do  # six trials an archive (a lent machine sends back files of 16 MiB at most)
  trials=($(cd runs/sweeps && ls -d "$name"/trial_*))
  for ((k = 0; k < ${#trials[@]}; k += 6)); do
    archive="$out/$name.$((k / 6 + 1)).tgz"
    tar czf "$archive" --exclude=train.csv -C runs/sweeps "$name/sweep.toml" "$name/local" "${trials[@]:k:6}" \
      && echo "$(basename "$archive"): $(du -h "$archive" | cut -f1)" | tee -a "$out/lent_sweeps.log"
  done
  tail -n 3 "$out/$name.log" | tee -a "$out/lent_sweeps.log"
done
