#!/bin/bash
# sweep.sh TAG "VARIANT ARGS" "EXTRA toml lines" MAT... : renders every scene with that variant, prints metrics
cd "${WORK:-.}"; tag=$1; var=$2; extra=$3; shift 3
mkdir -p out
for m in "$@"; do for l in front side back env; do
  [ -f ref/$m-$l-s2.exr ] || continue
  ex=(); [ -n "$extra" ] && for e in $extra; do ex+=(--extra "$e"); done
  VARIANT="$var" python3 "$(dirname "$0")/runqhm.py" ref/$m-$l.json out/$m-$l-$tag.exr --mode ${MODE:-full} "${ex[@]}" 2>>out/log-$tag.txt
  echo "$tag $m-$l $(python3 "$(dirname "$0")/compare.py" out/$m-$l-$tag.exr ref/$m-$l-s1.exr ref/$m-$l-s2.exr ref/$m-$l.json $SS)"
done; done
