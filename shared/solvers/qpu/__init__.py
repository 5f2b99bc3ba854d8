"""The QPU room of the solvers: what running on a D-Wave graph takes, apart from the samplers'
contract (:mod:`shared.solvers`) and the metering (:mod:`shared.solvers.meters`).

* embeddings: :mod:`~shared.solvers.qpu.structure_keys` (the keys), :mod:`~.embedding_search`
  (minorminer), :mod:`~.embedding_cache` (kept per bundle structure and target graph),
  :mod:`~.tile_embedding` (a grid tile's embedding from one cell's), :mod:`~.bundle_shapes`
  (a level's shapes, planned before its bundles fan out);
* packing: :mod:`~.packing` (a task's rests as disjoint copies in one call);
* the D-Wave adapters: :mod:`~.dwave` (``qpu``, ``qpu-sim``), :mod:`~.leap` (Leap's token,
  client and errors, held by composition by ``qpu`` and ``hybrid``), :mod:`~.qpu_settings`
  (chain strength, reverse anneals), :mod:`~.problems` (problem labels and ids),
  :mod:`~.cloud_errors` (the cloud client's errors and logs).
"""
