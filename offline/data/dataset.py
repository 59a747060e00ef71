"""Offline datasets, the public API: a pytree of transitions, versioned/checksummed files, and
the operations the offline learners need (thesis chapters 7–8, docs/design.md §2.4).

The names are defined in :mod:`offline.data.table` (the pytree and its invariants),
:mod:`offline.data.episodes` (host-side episode operations), :mod:`offline.data.files`
(:func:`save` / :func:`load`) and :mod:`offline.data.sampling` (in-graph operations); import
them from here.

A :class:`Dataset` holds ``N`` transitions as flat arrays

====================  ===========  ==========================================================
field                 shape        meaning
====================  ===========  ==========================================================
``observations``      ``(N, O)``   float, the state ``s`` the action was taken in
``actions``           ``(N, A)``   float, the action ``a``
``rewards``           ``(N,)``     float, the reward ``r(s, a)`` (or a relabelling of it)
``next_observations`` ``(N, O)``   float, the state ``s'`` reached (the *terminal* one on the
                                   last transition of an episode, not a reset observation)
``terminals``         ``(N,)``     bool, the episode ended in an absorbing state (collision)
``timeouts``          ``(N,)``     bool, the episode was cut by a time limit (or by the end of
                                   the rollout); *not* a terminal: learners bootstrap through it
``episode_ids``       ``(N,)``     int32, which episode the transition belongs to
====================  ===========  ==========================================================

plus ``metadata``, a JSON-serialisable dict (environment, behaviour policy, seed, recipe,
relabelling, …) kept outside the array pytree: it is static auxiliary data, so a dataset can be
passed through ``jax.jit`` / ``jax.device_put`` and keeps its metadata. Terminals and timeouts
are kept apart because they mean different Bellman targets — ``r + γ(1 − d)V(s')`` uses
``d = terminal`` only — and because cutting episodes at collisions is what creates the length
bias of thesis §8.3.3.

A dataset's ``metadata["env"]`` names the environment it was collected on (an :func:`envs.make`
name; :mod:`offline.data.collect` records it); :func:`check_environment` refuses the dataset for
another environment, naming both.

Invariants (checked by :func:`validate`, which :func:`create`, :func:`from_transitions`,
:func:`save` and :func:`load` call): equal leading sizes, the dtypes above (floating arrays of
one dtype per field, ``bool`` flags, ``int32`` ids ≥ 0), finite values, no transition both a
terminal and a timeout, every episode *contiguous* (its transitions adjacent, in time order) and
an end flag only on the last transition of its episode. Episode ids need not be dense: filtering
and splitting keep the original ids (so parts can be traced back); :func:`concatenate` and
:func:`renumber_episodes` make them ``0 … K−1`` in order of appearance.

Files (:func:`save` / :func:`load`): an uncompressed ``.npz``-style zip archive with one ``.npy``
member per field and a ``header.json`` member holding the format name and
:data:`FORMAT_VERSION`, every field's dtype, shape and SHA-256 of its raw (C-order) bytes, a
SHA-256 over all of that and the metadata. It is written to a temporary file in the target
directory, flushed to disk and moved into place with ``os.replace`` (never half-written). Loading
checks the archive, the header, the version, each member's zip CRC, dtype, shape and SHA-256,
then :func:`validate`; any failure raises :class:`DatasetFileError` naming the file and what is
wrong. A round trip is bit-exact (dtypes and bytes preserved). ``numpy.load`` reads the arrays of
such a file too (``np.load(path)["rewards"]``, without any check).

Host-side vs in-graph: :func:`sample` is a pure, jittable function (``batch_size`` static);
:func:`relabel_rewards` is jittable when its ``fn`` is. Everything whose output size depends on
the data (:func:`from_transitions`, :func:`filter_episodes`, :func:`split_by_episode`,
:func:`concatenate`, :func:`episode_statistics`) runs on the host in NumPy; move the result to
the accelerator once with ``jax.device_put(dataset)``.
"""

from offline.data.episodes import (
    EpisodeStats,
    concatenate,
    episode_bounds,
    episode_statistics,
    filter_episodes,
    from_transitions,
    split_by_episode,
    take_rows,
)
from offline.data.files import FORMAT_VERSION, DatasetFileError, load, save
from offline.data.sampling import RELABELLINGS, relabel_rewards, sample, sample_with
from offline.data.table import (
    FIELDS,
    Dataset,
    Metadata,
    TransitionTable,
    check_environment,
    create,
    environment_id,
    renumber_episodes,
    validate,
)

__all__ = [
    "FIELDS",
    "FORMAT_VERSION",
    "RELABELLINGS",
    "Dataset",
    "DatasetFileError",
    "EpisodeStats",
    "Metadata",
    "TransitionTable",
    "check_environment",
    "concatenate",
    "create",
    "environment_id",
    "episode_bounds",
    "episode_statistics",
    "filter_episodes",
    "from_transitions",
    "load",
    "relabel_rewards",
    "renumber_episodes",
    "sample",
    "sample_with",
    "save",
    "split_by_episode",
    "take_rows",
    "validate",
]
