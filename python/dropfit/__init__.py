"""dropfit from Python: run a drop-test session, read its results as numpy
arrays, simulate a fitted mat and step the co-simulation contact.

    import dropfit
    res = dropfit.run("samples/demo-session")            # or read_results("out")
    fit = res.fit                                        # the canonical fit.json
    sim = dropfit.simulate(fit, velocity_m_s=5.0)        # numpy arrays: t_s, grf_n, ...
    mat = dropfit.MatContact(fit)                        # fitting/cosim.h
    f = mat.step(0.002, 5.0, 1e-4)                       # f.foot_n, f.grf_n

Units are in the names (SI): _m, _s, _n, _kg. docs/python.md has the whole
interface; docs/formats.md the files behind Results.
"""
from ._dropfit import (ColumnContact, ContactForces, Error, Fit, InputError, MatContact, parse_fit, read_fit,
                       run_session, simulate)
from .results import Results, read_results, run

__all__ = ["ColumnContact", "ContactForces", "Error", "Fit", "InputError", "MatContact", "Results", "parse_fit", "read_fit",
           "read_results", "run", "run_session", "simulate"]
