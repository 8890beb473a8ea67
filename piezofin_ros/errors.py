"""One error base for the whole package, and one subclass per layer.

Every error the package raises on purpose is a :class:`PiezofinError`, so a caller (a node's
startup, the ``piezofin`` command line, a lab's script) catches the package's errors with one
``except PiezofinError`` and lets real bugs through.  Each layer has its own subclass, and each
specific error derives from its layer's class and, where the standard meaning fits, from the
builtin one too (a malformed fin file is also a ``ValueError``), so existing ``except ValueError``
code keeps working::

    PiezofinError
    +-- PhysicsError        physics/: FinConfigError, ModelError, bad operating points
    +-- BagError            bags/: unreadable or unwritable bags; BlockFormatError, MessageError
    +-- EstimationError     estimation/
    +-- RigError            rig/: a drive command or configuration the rig refuses
    +-- ControlError        control/: limits, plans, optimiser settings
    +-- DiagnosisError      diagnosis/: DataError (a recording that cannot be diagnosed)
    +-- NodeError           nodes/: StartupError; NodeFailed, LaunchArgumentError (launch files)
    +-- CliError            cli/: UsageError
    +-- TaskError           workers.py: a task that kills its worker, a Ray that cannot start
"""

from __future__ import annotations


class PiezofinError(Exception):
    """Any error this package raises on purpose."""


class PhysicsError(PiezofinError, ValueError):
    """A fin, a model or an operating point the physics cannot take."""


class BagError(PiezofinError, RuntimeError):
    """A bag that cannot be read or written (the message names the file)."""


class EstimationError(PiezofinError, ValueError):
    """Samples or settings the estimator cannot take."""


class RigError(PiezofinError, ValueError):
    """A drive command or rig configuration the rig refuses."""


class ControlError(PiezofinError, ValueError):
    """Limits, plans or optimiser settings that are not valid."""


class DiagnosisError(PiezofinError, ValueError):
    """A recording or a model the diagnosis cannot work with."""


class NodeError(PiezofinError, RuntimeError):
    """A node that cannot start or run."""


class CliError(PiezofinError):
    """A command line that cannot be carried out."""
