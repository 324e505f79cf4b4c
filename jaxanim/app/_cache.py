"""The command line's persistent compilation cache: where it lives, and turning it on for one command.

Every ``jaxanim`` command keeps the programs JAX compiles on disk, so that the next run with the
same shapes loads them instead of compiling again. The cache lives at

* ``$JAX_COMPILATION_CACHE_DIR`` when that variable is set (JAX's own name for it), else
* ``$XDG_CACHE_HOME/jaxanim`` when ``XDG_CACHE_HOME`` is set to an absolute path (the XDG base
  directory rule: a relative one is ignored), else
* ``~/.cache/jaxanim``.

Clear it with ``rm -rf ~/.cache/jaxanim`` (it only ever saves time; JAX checks its entries' keys,
which include the jax / jaxlib versions and the program). ``--no-compile-cache`` turns it off.

Every compilation is kept (``jax_persistent_cache_min_compile_time_secs = 0``, no minimum entry
size). Measured on ``jaxanim simulate --seconds 5`` (2 loaded cores): the run compiles 83 programs
(1 MB cached). With JAX's default threshold of 1 s only 6 of them were kept (the rollout and five
setup functions), and the second run still spent 20 s building the character, compiling the ~80
small eager ones again (14 s of CPU against 40 s cold); with every program kept the setup took
2.5 s and the second run 9.5 s of CPU. ``jaxanim ik`` (one target, the shipped clip) alike: its second
run took 12.9 s of CPU with the 1 s threshold (7 of 162 programs kept) and 7.6 s with every program
kept, against 24 s cold.

The library never turns the cache on: importing jaxanim leaves JAX's settings alone, and
:func:`compile_cache` puts them back when the command returns (``main`` may be called in-process).
"""

from __future__ import annotations

import contextlib
import os
import pathlib
from collections.abc import Iterator, Mapping

import jax
from jax.experimental.compilation_cache import compilation_cache as _jax_cache

#: The environment variable that overrides the location (read by JAX itself as well).
ENV_DIR = "JAX_COMPILATION_CACHE_DIR"
#: Keep every compilation: the many small ones of a command's setup add up (see the module docstring).
MIN_COMPILE_SECONDS = 0.0
MIN_ENTRY_BYTES = 0

_SETTINGS = (
    "jax_enable_compilation_cache",
    "jax_compilation_cache_dir",
    "jax_persistent_cache_min_compile_time_secs",
    "jax_persistent_cache_min_entry_size_bytes",
)


def compile_cache_dir(environ: Mapping[str, str] | None = None) -> pathlib.Path:
    """The cache directory: ``$JAX_COMPILATION_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxanim`` (absolute
    ``XDG_CACHE_HOME`` only), else ``$HOME/.cache/jaxanim``.

    Args:
        environ: the environment to read (default ``os.environ``).
    """
    env = os.environ if environ is None else environ
    explicit = env.get(ENV_DIR, "")
    if explicit:
        return pathlib.Path(explicit).expanduser()
    xdg = env.get("XDG_CACHE_HOME", "")
    if xdg and os.path.isabs(xdg):
        return pathlib.Path(xdg) / "jaxanim"
    home = env.get("HOME", "")
    return (pathlib.Path(home) if home else pathlib.Path.home()) / ".cache" / "jaxanim"


def _apply(settings: Mapping[str, object]) -> None:
    for name, value in settings.items():
        jax.config.update(name, value)
    _jax_cache.reset_cache()  # JAX reads the settings again at its next compilation


@contextlib.contextmanager
def compile_cache(path: str | os.PathLike | None) -> Iterator[None]:
    """Within the block JAX keeps every compilation in ``path`` (``None``: no persistent cache at all,
    even one that ``JAX_COMPILATION_CACHE_DIR`` asked JAX for); JAX's settings are restored after it."""
    saved = {name: getattr(jax.config, name) for name in _SETTINGS}
    if path is None:
        settings = {"jax_enable_compilation_cache": False}
    else:
        settings = {
            "jax_enable_compilation_cache": True,
            "jax_compilation_cache_dir": os.fspath(path),
            "jax_persistent_cache_min_compile_time_secs": MIN_COMPILE_SECONDS,
            "jax_persistent_cache_min_entry_size_bytes": MIN_ENTRY_BYTES,
        }
    _apply(settings)
    try:
        yield
    finally:
        _apply(saved)
