"""Whole-file checks of observation records shared by the RINEX 2 and RINEX 3/4 readers.

Both readers put the observations on a ``(time, sv)`` grid, where two records with the same
time tag would silently merge (the later wins) and a record whose time goes back would be
sorted into place. Neither happens in a file a receiver wrote: a repeated or re-stamped
epoch, or a body written several times, means the file is damaged, so the file is
rejected with the line of the offending epoch and the two times. A file cut inside its
last observation value is rejected too: the value's last digits are gone.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gnss_cli.errors import RinexFormatError

__all__ = ["check_epochs_increasing", "check_last_value_complete", "ns2iso"]


def ns2iso(time_ns: int) -> str:
    """Nanoseconds since 1970 (file time scale) as ISO 8601 text, without trailing zero decimals.

    >>> ns2iso(1_112_400_029_999_000_000)
    '2005-04-02T00:00:29.999'
    >>> ns2iso(1_112_400_030_000_000_000)
    '2005-04-02T00:00:30'
    """
    text = str(np.datetime64(int(time_ns), "ns"))
    return text.rstrip("0").rstrip(".") if "." in text else text


def check_epochs_increasing(times_ns: NDArray[np.int64], lineno: NDArray[np.int64], name: str) -> None:
    """Raise unless the epochs' times are strictly increasing.

    Parameters
    ----------
    times_ns : numpy.ndarray of int64, shape (n_epochs,)
        Time tags of the observation epochs (flags 0 and 1) in file order, nanoseconds
        since 1970 in the file's time scale (``datetime64[ns]`` is accepted too).
    lineno : numpy.ndarray of int64, shape (n_epochs,)
        File line number of each epoch line.
    name : str
        File name for the message.

    Raises
    ------
    RinexFormatError
        At the first epoch whose time is not later than the previous epoch's: a duplicate
        epoch, an epoch re-stamped with an earlier time, or a body written twice. The
        message names the file, both lines and both times.

    Examples
    --------
    >>> t = np.array([0, 30, 30], dtype=np.int64) * 1_000_000_000
    >>> check_epochs_increasing(t, np.array([20, 29, 38]), "a.obs")
    Traceback (most recent call last):
    ...
    gnss_cli.errors.RinexFormatError: a.obs: line 38: epoch 1970-01-01T00:00:30 is not later than the epoch 1970-01-01T00:00:30 on line 29 (repeated or out-of-order epoch)
    """
    t = np.asarray(times_ns).astype(np.int64)
    if t.size < 2:
        return
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise RinexFormatError(
            f"{name}: line {int(lineno[i])}: epoch {ns2iso(int(t[i]))} is not later than the epoch "
            f"{ns2iso(int(t[i - 1]))} on line {int(lineno[i - 1])} (repeated or out-of-order epoch)"
        )


def check_last_value_complete(length: int, first_col: int, lineno: int, name: str) -> None:
    """Raise when a file that ends without a line end stops inside an observation value.

    Observation fields are 16 characters, ``F14.3`` then the loss-of-lock and strength
    digits, from column ``first_col`` (0-based: 0 in RINEX 2, 3 after the satellite id in
    RINEX 3/4). Values are right-aligned, so a last line whose end falls inside the 14
    value characters of a field has lost the value's last digits: reading it would give a
    wrong number (``24767686.375`` cut to ``2476768``). Call only for a last line without
    a line end that holds observations.

    Parameters
    ----------
    length : int
        Characters of the last line (without ``\\r``).
    first_col : int
        Column of the first observation field.
    lineno : int
        File line number of the last line.
    name : str
        File name for the message.

    Raises
    ------
    RinexFormatError
        The file was cut inside a value.

    Examples
    --------
    >>> check_last_value_complete(3 + 16 + 14, 3, 9, "a.rnx")  # ends after a whole value
    >>> check_last_value_complete(3 + 16 + 9, 3, 9, "a.rnx")
    Traceback (most recent call last):
    ...
    gnss_cli.errors.RinexFormatError: a.rnx: line 9: the file ends inside observation 2 of the line (truncated file)
    """
    inside = length - first_col
    if inside > 0 and 0 < inside % 16 < 14:
        raise RinexFormatError(
            f"{name}: line {lineno}: the file ends inside observation {inside // 16 + 1} of the line (truncated file)"
        )
