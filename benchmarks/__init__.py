"""cstorm's benchmarks (see README.md here). Importing the package tunes glibc's malloc
before JAX starts (`cstorm.tune_allocator`: XLA's large temporary buffers of batched
calls are then reused instead of faulted in afresh on every call), as the ``cstorm``
command does; ``CSTORM_MALLOC=system`` keeps glibc's defaults, to measure both."""

from cstorm.allocator import tune_allocator as _tune

_tune(late="skip")
