#!/usr/bin/env bash
# End-to-end scan figures of the streaming scan, shards and Open MPI:
#   1. the HELIOS-like scene (scenes/ground_blocks.toml: 140 m ground plane and
#      blocks, 1,112 triangles; 1.44 M pulses over -40..60 x -25..90 degrees,
#      10 kW, 1 shot, LAS) on 2 threads at 1 and 19 rays: pulses/s, peak RSS;
#   2. saturated (10 kW) against weak (1 W) echoes, 1 ray, 1 thread;
#   3. mpirun -np 2 (1 thread each) against 1 process of 2 threads;
#   4. throughput and peak RSS against beam count (LAS + npy, 2 threads).
# Medians of REPEAT runs (default 3). Usage: bench/cluster_bench.sh [BUILD_DIR]
set -euo pipefail
build=${1:-build}
tofkit=$(realpath "$build/tofkit")
here=$(cd "$(dirname "$0")" && pwd)
scene=$here/scenes/ground_blocks.toml
repeat=${REPEAT:-3}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
az=-40:60:0.0833333333
el=-25:90:0.0958333333

# median wall seconds and the largest peak RSS (MB) of REPEAT runs of "$@"
measure() {
  local times=() rss=0
  for ((i = 0; i < repeat; i++)); do
    rm -rf "$work/out" && mkdir "$work/out"
    /usr/bin/time -f "%e %M" -o "$work/time" "$@" --out "$work/out" 2>/dev/null >/dev/null
    read -r t m <"$work/time"
    times+=("$t")
    ((m > rss)) && rss=$m
  done
  local median
  median=$(printf '%s\n' "${times[@]}" | sort -g | sed -n "$(((repeat + 1) / 2))p")
  echo "$median $((rss / 1024))"
}

scan() {  # threads power rays [extra...]
  local threads=$1 power=$2 rays=$3
  shift 3
  echo "$tofkit --threads $threads --max-rows 100000000 --set laser.peak_power_w=$power --set scan.rays_per_beam=$rays scan --scene $scene --pattern spherical --shots 1 $*"
}

pulses=1442401
echo "# 1. HELIOS-like scene, 1.44 M pulses, 10 kW, 1 shot, LAS, 2 threads"
for rays in 1 19; do
  read -r t m < <(measure $(scan 2 10000 "$rays" --azimuth=$az --elevation=$el --write las))
  echo "rays $rays: $t s, $(awk -v p=$pulses -v t="$t" 'BEGIN{printf "%.2f", p/t/1e6}') M pulses/s, peak $m MB"
done

echo "# 2. saturated (10 kW) vs weak (1 W) echoes, 1 ray, 1 thread, LAS"
read -r ts _ < <(measure $(scan 1 10000 1 --azimuth=$az --elevation=$el --write las))
read -r tw _ < <(measure $(scan 1 1 1 --azimuth=$az --elevation=$el --write las))
echo "10 kW $ts s, 1 W $tw s: ratio $(awk -v a="$ts" -v b="$tw" 'BEGIN{printf "%.2f", a/b}')"

if command -v mpirun >/dev/null; then
  echo "# 3. mpirun -np 2 x 1 thread vs 1 process x 2 threads (same scan, LAS)"
  read -r t1 _ < <(measure $(scan 2 10000 1 --azimuth=$az --elevation=$el --write las))
  # (--bind-to none: on a shared machine a rank pinned to a busy core waits)
  read -r t2 _ < <(measure mpirun --allow-run-as-root --oversubscribe --bind-to none -np 2 $(scan 1 10000 1 --azimuth=$az --elevation=$el --write las))
  echo "1 x 2 threads $t1 s, 2 ranks x 1 thread $t2 s: ranks reach $(awk -v a="$t1" -v b="$t2" 'BEGIN{printf "%.0f", 100*a/b}') % of the threads' throughput"
else
  echo "# 3. skipped: mpirun is missing"
fi

echo "# 4. beams vs time and peak RSS (LAS + npy, 1 ray, 10 kW, 2 threads)"
for step in 0.3 0.1 0.05 0.03; do
  read -r t m < <(measure $(scan 2 10000 1 --azimuth=-40:60:$step --elevation=-25:90:$step --write las,npy))
  beams=$(awk -v s=$step 'BEGIN{printf "%d", (int(100/s+1e-9)+1)*(int(115/s+1e-9)+1)}')
  echo "beams $beams: $t s, $(awk -v b="$beams" -v t="$t" 'BEGIN{printf "%.0f", t/b*1e9}') ns/beam, peak $m MB"
done
