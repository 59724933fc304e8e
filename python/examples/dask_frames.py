"""Infer a long sequence with Dask: one task per block of frames.

    python examples/dask_frames.py SCENE_DIR [BLOCK] [WORKERS]

Each task reads the scene folder itself (on a cluster: a shared file system)
and infers frames a..b, as `grainforce infer --frames a..b` does:
accelerations derived from the tracks still see the whole tracks, so the
blocks' forces are those of one run over all frames. The blocks' tables are
concatenated in frame order.
"""

import sys

import pandas as pd

import grainforce as gf


def infer_block(scene_dir, first, last, options):
    """One task: frames first..last of the sequence in scene_dir (only those
    frames, and the filter's margin, are read)."""
    return gf.infer(scene_dir, frames=(first, last), **options).forces


def infer_in_blocks(client, scene_dir, block=20, frames=None, **options):
    """The forces of every frame, one Dask task per `block` frames.

    frames: (first, last) frame numbers; read from the scene when not given
    (which reads it whole once, here)."""
    if frames is None:
        numbers = [f for f in gf.read_scene(scene_dir).frames if f is not None]
        if not numbers:
            raise ValueError(f"{scene_dir}: not a sequence (no frame column)")
        frames = (min(numbers), max(numbers))
    first, last = frames
    tasks = [
        client.submit(infer_block, scene_dir, a, min(a + block - 1, last), options, pure=False)
        for a in range(first, last + 1, block)
    ]
    return pd.concat(client.gather(tasks), ignore_index=True)


if __name__ == "__main__":
    from dask.distributed import Client, LocalCluster

    scene_dir = sys.argv[1]
    block = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    workers = int(sys.argv[3]) if len(sys.argv) > 3 else 2
    with LocalCluster(n_workers=workers, threads_per_worker=1) as cluster, Client(cluster) as client:
        forces = infer_in_blocks(client, scene_dir, block, method="dynamic")
    forces.to_csv("forces.csv", index=False)
    print(f"{len(forces)} forces over {forces['frame'].nunique()} frames written to forces.csv")
