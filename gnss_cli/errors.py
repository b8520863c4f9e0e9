"""Exception hierarchy with the process exit codes of the command-line tools.

Every error the tools report on purpose derives from :class:`GnssError`, carries an
``exit_code`` and also derives from the matching builtin so that library users can catch
``ValueError`` / ``FileNotFoundError`` as usual.

Exit codes
----------
0  success
1  bug (a traceback is printed only with ``--debug``)
2  usage: bad command-line arguments or bad arguments to a library function
3  bad configuration file or option value
4  missing, unreadable or malformed input (not RINEX, wrong RINEX type, no data)
5  the run completed but produced no solution for an input
6  an output file could not be written (read-only folder, disk full, not a folder)
130, 143  interrupted by SIGINT (Ctrl-C) or terminated by SIGTERM
"""

from __future__ import annotations


class GnssError(Exception):
    """Base of every error gnss-solve reports on purpose."""

    exit_code: int = 1


class UsageError(GnssError, ValueError):
    """Bad arguments: wrong shape, non-finite values, unknown method names."""

    exit_code = 2


class ConfigError(GnssError, ValueError):
    """A configuration file or option value is invalid."""

    exit_code = 3


class KeywordError(ConfigError, TypeError):
    """A keyword argument of the Python API that is not an option (it names the nearest one)."""


class InputError(GnssError):
    """An input file is missing, unreadable or not what it should be."""

    exit_code = 4


class InputFileNotFoundError(InputError, FileNotFoundError):
    """An input path does not exist or is not a readable file."""


class RinexFormatError(InputError, ValueError):
    """A file is not valid RINEX of the expected kind, or holds no usable data."""


class NoSolutionError(GnssError, RuntimeError):
    """Processing ran but no epoch could be solved."""

    exit_code = 5


class OutputError(GnssError, OSError):
    """An output file could not be written; nothing of the run's output is left behind."""

    exit_code = 6
