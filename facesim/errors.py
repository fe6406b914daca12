"""The two kinds of error facesim reports to a user as one line, without a traceback.

InputError: something the user gave is wrong (exit code 2 from the CLI).
SimulationError: a valid input whose simulation blew up (exit code 1), naming the frame.
"""


class FacesimError(Exception):
    exit_code = 1


class InputError(FacesimError):
    exit_code = 2


class SimulationError(FacesimError):
    exit_code = 1

    def __init__(self, message: str, frame: int | None = None):
        super().__init__(message)
        self.frame = frame


class RenderError(FacesimError):
    exit_code = 1
