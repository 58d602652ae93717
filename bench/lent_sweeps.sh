#!/usr/bin/env bash
# Advance sweeps on a machine without Ray (a lent GPU machine's CPU cores, say) for SECONDS, then pack each
# sweep's folder (training logs and each trial's latest checkpoint) into $OUT/<name>.<k>.tgz (four trials each, PER_ARCHIVE to change) to carry back. Each
# FILE:N runs N of the file's trials at a time (train.sweep.local, as `colorgrid sweep run FILE --local N`).
# Back here: tar xzf <name>.<k>.tgz -C runs/sweeps, then continue with `colorgrid sweep run FILE --local N`, or
# keep the finished trials with `colorgrid sweep publish runs/sweeps/<name>`. The project must be importable
# (PYTHONPATH), as bench/gpu_measure.sh says.
# Usage: bash bench/lent_sweeps.sh SECONDS sweeps/paper_table1_eighth.toml:12 sweeps/assistant_recipe.toml:4
set -u
seconds=$1; shift
per=${PER_ARCHIVE:-4}  # trials an archive: about 3 MB each, and a lent machine sends back files of 16 MiB at most
[[ $per =~ ^[1-9][0-9]*$ ]] || { echo "PER_ARCHIVE must be a whole number >= 1, got '$per'" >&2; exit 2; }
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
for name in "${names[@]}"; do
  trials=($(cd runs/sweeps && ls -d "$name"/trial_*))
  for ((k = 0; k < ${#trials[@]}; k += per)); do
    archive="$out/$name.$((k / per + 1)).tgz"
    tar czf "$archive" --exclude=train.csv -C runs/sweeps "$name/sweep.toml" "$name/local" "${trials[@]:k:per}" \
      && echo "$(basename "$archive"): $(du -h "$archive" | cut -f1)" | tee -a "$out/lent_sweeps.log"
  done
  tail -n 3 "$out/$name.log" | tee -a "$out/lent_sweeps.log"
done
