"""The errors fem-impact raises on purpose (importable without dolfinx or PETSc).

Every one derives from :class:`FemImpactError`, so a script can catch them all at once (an argument
of a wrong Python type is a TypeError that says what the function takes: :func:`wrong_type`):

- :class:`CaseError`: bad input, found before anything runs (names the key, and the file and
  line when the case came from a file);
- :class:`SimulationError`: the run itself cannot go on (blow-up, NaN, a contact problem
  without solution, energy created when asked to stop on it).
"""


class FemImpactError(Exception):
    """Base class of every error fem-impact raises on purpose."""


class CaseError(FemImpactError):
    """Bad input: names the key (dotted path), and where known the file and line, and what is wrong.

    Parameters
    ----------
    file : str or None
        The case file as shown to the user, ``"--set"`` for a command-line option, or None
        for a case built in Python (``Case.from_dict``).
    key : str or None
        Dotted key path, e.g. ``"contacts[0].normal"``.
    line : int or None
        1-based line in `file`.
    message : str
        What is wrong.
    """

    def __init__(self, file, key, line, message):
        super().__init__(file, key, line, message)
        self.file = None if file is None else str(file)
        self.key, self.line, self.message = key, line, message

    def __str__(self):
        where = (f"{self.file}:{self.line}" if self.line else self.file) if self.file else None
        text = f"{self.key}: {self.message}" if self.key else self.message
        return one_line(f"{where}: {text}" if where else text)


def one_line(text: str) -> str:
    """``text`` with its line breaks and other unprintable characters escaped (``\\n``): a key or a file name
    may hold them, and a message must stay one line."""
    return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def type_name(value) -> str:
    """How a TypeError names what it got: ``None``, or the type's name."""
    return "None" if value is None else type(value).__name__


def wrong_type(call: str, takes: str, value) -> TypeError:
    """The TypeError of the API for an argument of a wrong Python type: what `call` takes and what it got."""
    return TypeError(f"{call} takes {takes}, got {type_name(value)}")


class OutputFolderError(CaseError):
    """An output folder or file that cannot or must not be written (bad input: status 2)."""

    def __init__(self, where, message):
        super().__init__(where, None, None, message)


class ModelInputError(FemImpactError):
    """Input that does not fit the model, found while building it (a node group the mesh lacks, a
    vector with a component the mesh has not): raised by the model builders with the key path of
    the case that gave it; the front end (``Case.errors_at_keys``) turns it into a CaseError with
    the file and line.
    """

    def __init__(self, key, message):
        super().__init__(key, message)
        self.key, self.message = tuple(key), message

    def __str__(self):
        return f"{'.'.join(map(str, self.key))}: {self.message}" if self.key else self.message


class SimulationError(FemImpactError, RuntimeError):
    """The run cannot go on (blow-up, NaN, a contact problem without solution)."""


class ContactSolverError(SimulationError):
    """The small contact problem could not be solved (singular or ill-posed constraints)."""
