#!/bin/sh
# Fills fuzz/corpus/<target>/ with the project's fixtures and the small hand-made
# seeds in fuzz/seeds/. Several files of one input are joined by the separator
# in readers.rs ("\n@@@@\n"). Run from anywhere; corpus/ is git-ignored.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
fixtures="$here/../fixtures"
corpus="$here/corpus"
sep='\n@@@@\n'

join() { # join OUT FILE... : FILEs joined by the separator into OUT
    out=$1; shift
    first=1
    for f in "$@"; do
        [ $first = 1 ] || printf "$sep"
        cat "$f"
        first=0
    done > "$out"
}

for t in scene lammps liggghts yade gff pegs image; do
    mkdir -p "$corpus/$t"
    cp "$here/seeds/$t/"* "$corpus/$t/" 2>/dev/null || true
done

# The larger regression scenes add little over these and slow every execution.
for d in "$fixtures/oedometer" "$fixtures/regression/oedometer3d_seed1" "$fixtures/regression/box3d_seed1"; do
    d=${d%/}
    set -- "$d/scene.json" "$d/grains.csv" "$d/contacts.csv"
    if [ -f "$d/walls.csv" ]; then set -- "$@" "$d/walls.csv"; fi
    if [ -f "$d/forces.csv" ]; then set -- "$@" "$d/forces.csv"; fi
    join "$corpus/scene/fixture-$(basename "$d")" "$@"
done
i="$fixtures/import"
join "$corpus/lammps/fixture" "$i/lammps/atoms.dump" "$i/lammps/pairs.dump"
join "$corpus/liggghts/fixture" "$i/liggghts/atoms.dump" "$i/liggghts/pairs.dump"
join "$corpus/yade/fixture" "$i/yade/bodies.csv" "$i/yade/interactions.csv"
join "$corpus/gff/fixture" "$i/gff/grains.gff" "$i/gff/contacts.csv"
join "$corpus/gff/fixture-tomography" "$i/gff/grains.gff" "$i/gff/contacts.csv" "$i/gff/tomo_grains.csv"
join "$corpus/pegs/fixture" "$i/pegs/box_solved_compressed.mat" "$i/pegs/box_centers.txt"
cp "$i/pegs/box_contacts.mat" "$corpus/pegs/fixture-contacts"
echo "seeded $corpus"
