"""The one exception type the CLI turns into a single clear line on stderr and a non-zero exit."""


class BCBenchError(Exception):
    """A user-facing error: bad input, missing data, invalid option. Its message is the whole story."""


class DatasetError(BCBenchError):
    """The Push-T dataset is missing, corrupt or has the wrong structure."""
