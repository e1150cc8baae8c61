"""mlsim: a physically based simulator of a mechanoluminescent visuotactile sensor.

See README.md for the two commands (``make demo``, ``make test``) and a tour. Importing mlsim is
cheap: stages import their heavy dependencies (pytetwild, mitsuba, torch) only when they run.
"""

__version__ = "0.1.0"
