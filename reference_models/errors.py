r'''Exceptions raised for bad camera models and bad model files

Every user-facing error of camval derives from CamvalError; the command line
prints such an error in one line (no traceback) and exits with status 2.
'''


class CamvalError(Exception):
    '''Base of every error caused by user input (files, options, campaigns).'''


class ModelError(CamvalError, ValueError):
    '''A camera model whose numbers are degenerate or inconsistent.'''


class ModelFileError(ModelError):
    r'''A camera-model file that cannot be read

ARGUMENTS

- path: the file
- line: 1-based line number of the offending line, or None for the whole file
- problem: what was found and what was expected
'''

    def __init__(self, path, line, problem):
        self.path = str(path)
        self.line = line
        self.problem = problem
        where = f"'{self.path}'" + (f", line {line}" if line is not None else "")
        super().__init__(f"{where}: {problem}")


class UnknownCameraError(CamvalError, KeyError):
    '''A camera id or name that the catalogue does not have.'''

    def __str__(self):
        return str(self.args[0])


class NotRepresentableError(ModelError):
    '''A model that another library (mrcal, OpenCV) cannot represent exactly.'''
