"""Limits on what input may make penumbra allocate, and strict integer conversion.

A small file must not cost gigabytes: every allocation whose size a file (or
an argument) decides is checked first against

* what the input itself can hold, where the format allows knowing it (a header
  may not promise more data than the file contains), and
* a cap: :func:`max_bytes` (environment variable ``PENUMBRA_MAX_BYTES``,
  default 8 GiB; the native library reads the same variable for its own
  allocations) and, for images, :func:`max_pixels` (``PENUMBRA_MAX_PIXELS``,
  default 2**28, a 16384 x 16384 image).

Refusals are :class:`~penumbra.errors.InputError` naming the limit and the
variable that sets it (docs/reliability.md).

:func:`checked_int` converts a value to an integer of a C type's range, refusing
(never wrapping) a value that is not a whole number or does not fit.
"""

from __future__ import annotations

import numbers
import re
import os

from .errors import InputError

MAX_BYTES_VAR = "PENUMBRA_MAX_BYTES"
MAX_PIXELS_VAR = "PENUMBRA_MAX_PIXELS"
DEFAULT_MAX_BYTES = 8 << 30
DEFAULT_MAX_PIXELS = 1 << 28

# Ranges of the C integer types the bindings pass values as.
INT32 = (-(1 << 31), (1 << 31) - 1)
UINT32 = (0, (1 << 32) - 1)
INT64 = (-(1 << 63), (1 << 63) - 1)
UINT64 = (0, (1 << 64) - 1)


def _env_limit(var: str, default: int) -> int:
    text = os.environ.get(var, "").strip()
    if not text:
        return default
    try:
        value = int(text, 10)
    except ValueError:
        value = -1
    if value <= 0:
        raise InputError(f"{var}={text!r} is not a positive whole number (unset it for the default, {default})")
    return value


def max_bytes() -> int:
    """The most bytes one input may make penumbra allocate (``PENUMBRA_MAX_BYTES``, default 8 GiB)."""
    return _env_limit(MAX_BYTES_VAR, DEFAULT_MAX_BYTES)


def max_pixels() -> int:
    """The most pixels an image read from a file may have (``PENUMBRA_MAX_PIXELS``, default 2**28)."""
    return _env_limit(MAX_PIXELS_VAR, DEFAULT_MAX_PIXELS)


def _size(n: int) -> str:
    for unit, shift in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if n >= 1 << shift:
            return f"{n / (1 << shift):.3g} {unit}"
    return f"{n} bytes"


def check_bytes(nbytes: int, what: str, where: str) -> None:
    """Refuse (InputError) when ``what`` in ``where`` would need more than :func:`max_bytes`."""
    limit = max_bytes()
    if nbytes > limit:
        raise InputError(f"{where}: {what} would need {_size(nbytes)} of memory, more than the limit of "
                         f"{_size(limit)} (set {MAX_BYTES_VAR} to raise it)")


def check_image(width: int, height: int, bytes_per_pixel: int, where: str, what: str = "the image") -> None:
    """Refuse an image of width x height pixels over the pixel cap, or whose decoding
    (``bytes_per_pixel`` at its peak) would need more than :func:`max_bytes`."""
    pixels = int(width) * int(height)
    limit = max_pixels()
    if pixels > limit:
        raise InputError(f"{where}: {what} is {width} x {height} = {pixels} pixels, more than the limit of "
                         f"{limit} (set {MAX_PIXELS_VAR} to raise it)")
    check_bytes(pixels * int(bytes_per_pixel), f"decoding {what} ({width} x {height})", where)


def check_data(needed: int, available: int, what: str, where: str) -> None:
    """Refuse a header that promises more bytes of data than the file holds."""
    if needed > available:
        raise InputError(f"{where}: truncated or corrupt file: {what} needs {needed} bytes, the file holds "
                         f"{available}")


def checked_int(value, what: str, lo: int = UINT32[0], hi: int = UINT32[1]) -> int:
    """``value`` as a Python int in [lo, hi]; refuses (InputError) anything that is not
    a whole number (bools, fractions, strings, NaN) or does not fit, instead of wrapping."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{what} must be a whole number, got {value!r}")
    if isinstance(value, numbers.Integral):
        number = int(value)
    else:
        try:
            exact = float(value).is_integer()
        except (OverflowError, ValueError):
            exact = False
        if not exact:
            raise InputError(f"{what} must be a whole number, got {value!r}")
        number = int(value)
    if not lo <= number <= hi:
        raise InputError(f"{what} must be in [{lo}, {hi}], got {number}")
    return number


_DECIMAL = re.compile(r"[+-]?[0-9]{1,30}")


def parse_int(token: str | bytes, what: str, lo: int = INT64[0], hi: int = INT64[1]) -> int:
    """A decimal integer token from a file, strictly: optional sign and ASCII digits only
    (no fractions, exponents, underscores or trailing characters), in [lo, hi]; else InputError."""
    text = token.decode("latin-1") if isinstance(token, (bytes, bytearray)) else str(token)
    if not _DECIMAL.fullmatch(text):
        raise InputError(f"{what}: {text[:40]!r} is not an integer")
    value = int(text)
    if not lo <= value <= hi:
        raise InputError(f"{what}: {value} is out of range [{lo}, {hi}]")
    return value
