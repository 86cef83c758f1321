"""The capture's files on disk: the output folder (``folder``), each rendered frame's files (``files.frame_files``)
and their check (``verify``), per-shard state files (``shards``) and the dataset files (``write``)."""
