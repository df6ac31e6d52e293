#!/usr/bin/env bash
# End-to-end scan figures of the streaming scan, shards and Open MPI:
#   1. the HELIOS-like scene (scenes/ground_blocks.toml: 140 m ground plane and
#      blocks, 1,112 triangles; 1.44 M pulses over -40..60 x -25..90 degrees,
#      10 kW, 1 shot, LAS) on 2 threads at 1 and 19 rays: pulses/s, peak RSS;
#   2. saturated (10 kW) against weak (1 W) echoes, 1 ray, 1 thread;
#   3. mpirun -np 2 (1 thread each) against 1 process of 2 threads;
#   4. throughput and peak RSS against beam count (LAS + npy, 2 threads);
#   5. (BIG=1) the same on a 10^6-triangle ground at 10^6, 10^7 and 10^8 beams
#      (the last writes 2 GB and takes about 30 s quiet).
# SECTIONS="1 3" runs only those sections.
# The factory calibration is read from a cache warmed before the timed runs
# (a unit keeps its calibration; io/calibration_cache.hpp), in a temporary
# directory: CACHE=cold makes every run calibrate (TOFKIT_CACHE_DIR=off).
# Each run gives three times: the wall clock (end to end: start-up, the scene
# file, the BVH, the scan and its files), the scan
# alone (the beams measured and written: what grows with the beams) and the
# set-up before it, both from the scan's summary line. Medians of REPEAT runs
# (default 3). BASE=path/to/tofkit runs another build interleaved with this
# one (A B A B ...) and prints it beside: on a shared machine only ratios
# measured in the same run mean much.
# Usage: [BASE=...] [REPEAT=3] [BIG=1] [SECTIONS="..."] bench/cluster_bench.sh [BUILD_DIR]
set -euo pipefail
build=${1:-build}
tofkit=$(realpath "$build/tofkit")
base=${BASE:+$(realpath "$BASE")}
here=$(cd "$(dirname "$0")" && pwd)
scene=$here/scenes/ground_blocks.toml
repeat=${REPEAT:-3}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
if [[ ${CACHE:-warm} == cold ]]; then
  export TOFKIT_CACHE_DIR=off
else
  export TOFKIT_CACHE_DIR=$work/cache
fi
az=-40:60:0.0833333333
el=-25:90:0.0958333333
binaries=("$tofkit")
[[ -n "$base" ]] && binaries+=("$base")

median() { sort -g | sed -n "$(((repeat + 1) / 2))p"; }
med() {  # the median of a space-separated list, "?" if it is empty (an older build's summary)
  local v
  v=$(tr ' ' '\n' <<<"$1" | grep . | median || true)
  echo "${v:-?}"
}

# "wall scan setup rss_MB" (medians; the largest RSS) of REPEAT runs of
# `LAUNCH... BIN ARGS...` for each binary, interleaved; one line per binary.
# Usage: measure "LAUNCH" ARGS...   (LAUNCH may be empty)
measure() {
  local launch=$1
  shift
  local -A walls scans setups rss
  for ((i = 0; i < repeat; i++)); do
    for b in "${binaries[@]}"; do
      rm -rf "$work/out" && mkdir "$work/out"
      # shellcheck disable=SC2086
      /usr/bin/time -f "%e %M" -o "$work/time" $launch "$b" "$@" --out "$work/out" \
        2>"$work/err" >/dev/null
      read -r t m <"$work/time"
      local line
      line=$(grep -o '[0-9.]* s on [0-9]* thread(s)\( after [0-9.]* s\)\?' "$work/err" || true)
      walls[$b]+="$t "
      scans[$b]+="$(echo "$line" | awk '{print $1}') "
      setups[$b]+="$(echo "$line" | awk '{print $7}') "
      ((m / 1024 > ${rss[$b]:-0})) && rss[$b]=$((m / 1024))
    done
  done
  for b in "${binaries[@]}"; do
    echo "$(med "${walls[$b]}") $(med "${scans[$b]}") $(med "${setups[$b]}") ${rss[$b]}"
  done
}

name() { [[ $1 == "$tofkit" ]] && echo "this build" || echo "BASE"; }

# Each build's factory calibrations of the bench's devices (10 kW and 1 W)
# into the cache: a one-beam scan each.
for b in "${binaries[@]}"; do
  for power in 10000 1; do
    rm -rf "$work/out" && mkdir "$work/out"
    "$b" --set laser.peak_power_w=$power scan --scene "$scene" --pattern spherical --shots 1 \
      --azimuth=0 --elevation=-10 --write las --out "$work/out" 2>/dev/null >/dev/null
  done
done

scan_args() {  # threads power rays [extra...]
  local threads=$1 power=$2 rays=$3
  shift 3
  echo "--threads $threads --max-rows 1000000000 --set laser.peak_power_w=$power --set scan.rays_per_beam=$rays scan --scene $scene --pattern spherical --shots 1 $*"
}

# The beams of a spherical pattern over azimuth and elevation ranges (start:stop:step).
beams_of() {
  awk -v a="$1" -v e="$2" 'BEGIN{split(a, x, ":"); split(e, y, ":");
    printf "%d", (int((x[2]-x[1])/x[3]+1e-9)+1)*(int((y[2]-y[1])/y[3]+1e-9)+1)}'
}

# Sections to run: SECTIONS (default "1 2 3 4", and 5 with BIG=1).
sections=${SECTIONS:-"1 2 3 4${BIG:+ 5}"}
want() { [[ " $sections " == *" $1 "* ]]; }

rate() { awk -v p="$1" -v t="$2" 'BEGIN{printf "%.2f", p/t/1e6}'; }

pulses=1442401
want 1 && echo "# 1. HELIOS-like scene, 1.44 M pulses, 10 kW, 1 shot, LAS, 2 threads"
for rays in 1 19; do
  want 1 || break
  mapfile -t rows < <(measure "" $(scan_args 2 10000 "$rays" --azimuth=$az --elevation=$el --write las))
  for k in "${!binaries[@]}"; do
    read -r t s u m <<<"${rows[$k]}"
    echo "rays $rays, $(name "${binaries[$k]}"): end to end $t s ($(rate $pulses "$t") M pulses/s); scan $s s ($(rate $pulses "$s") M pulses/s) after $u s of set-up; peak $m MB"
  done
done

if want 2; then
echo "# 2. saturated (10 kW) vs weak (1 W) echoes, 1 ray, 1 thread, LAS (scan alone)"
mapfile -t strong < <(measure "" $(scan_args 1 10000 1 --azimuth=$az --elevation=$el --write las))
mapfile -t weak < <(measure "" $(scan_args 1 1 1 --azimuth=$az --elevation=$el --write las))
for k in "${!binaries[@]}"; do
  read -r _ ts _ _ <<<"${strong[$k]}"
  read -r _ tw _ _ <<<"${weak[$k]}"
  echo "$(name "${binaries[$k]}"): 10 kW $ts s, 1 W $tw s: ratio $(awk -v a="$ts" -v b="$tw" 'BEGIN{printf "%.2f", a/b}')"
done
fi

if ! want 3; then
  :
elif command -v mpirun >/dev/null; then
  echo "# 3. mpirun -np 2 x 1 thread vs 1 process x 2 threads (same scan, LAS; 1.44 M and 12.8 M beams)"
  # (--bind-to none: on a shared machine a rank pinned to a busy core waits)
  mpi="mpirun --oversubscribe --bind-to none -np 2"
  [[ $(id -u) == 0 ]] && mpi="mpirun --allow-run-as-root --oversubscribe --bind-to none -np 2"
  for grid in "$az $el" "-40:60:0.03 -25:90:0.03"; do
    read -r a e <<<"$grid"
    mapfile -t one < <(measure "" $(scan_args 2 10000 1 --azimuth=$a --elevation=$e --write las))
    mapfile -t two < <(measure "$mpi" $(scan_args 1 10000 1 --azimuth=$a --elevation=$e --write las))
    for k in "${!binaries[@]}"; do
      read -r t1 s1 _ _ <<<"${one[$k]}"
      read -r t2 s2 _ _ <<<"${two[$k]}"
      echo "$(beams_of "$a" "$e") beams, $(name "${binaries[$k]}"): 1 x 2 threads scan $s1 s (wall $t1 s), 2 ranks x 1 thread scan $s2 s (wall $t2 s): ranks reach $(awk -v a="$s1" -v b="$s2" 'BEGIN{printf "%.0f", 100*a/b}') % of the threads' scan throughput ($(awk -v a="$t1" -v b="$t2" 'BEGIN{printf "%.0f", 100*a/b}') % end to end)"
    done
  done
else
  echo "# 3. skipped: mpirun is missing"
fi

per_beam() {  # scene label steps...
  local scn=$1 label=$2
  shift 2
  for step in "$@"; do
    mapfile -t rows < <(measure "" --threads 2 --max-rows 1000000000 --set laser.peak_power_w=10000 scan --scene "$scn" --pattern spherical --shots 1 --azimuth=-40:60:$step --elevation=-25:90:$step --write las,npy)
    local beams
    beams=$(awk -v s="$step" 'BEGIN{printf "%d", (int(100/s+1e-9)+1)*(int(115/s+1e-9)+1)}')
    for k in "${!binaries[@]}"; do
      read -r t s u m <<<"${rows[$k]}"
      echo "$label, $(name "${binaries[$k]}"), $beams beams: scan $s s, $(awk -v b="$beams" -v t="$s" 'BEGIN{printf "%.0f", t/b*1e9}') ns/beam (end to end $t s, $(awk -v b="$beams" -v t="$t" 'BEGIN{printf "%.0f", t/b*1e9}') ns/beam; set-up $u s); peak $m MB"
    done
  done
}

if want 4; then
  echo "# 4. beams vs time and peak RSS (LAS + npy, 1 ray, 10 kW, 2 threads)"
  per_beam "$scene" "blocks" 0.3 0.1 0.05 0.03
fi

if want 5; then
  echo "# 5. a 10^6-triangle ground: 10^6, 10^7, 10^8 beams (LAS + npy, 2 threads)"
  python3 "$here/scenes/make_ground_blocks.py" 707 "$work/ground_1m.obj"
  sed 's/ground_blocks.obj/ground_1m.obj/' "$scene" >"$work/ground_1m.toml"
  per_beam "$work/ground_1m.toml" "10^6 triangles" 0.1074 0.0339 0.01072
fi
