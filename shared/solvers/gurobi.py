"""``gurobi``: the bundle's QUBO as a binary quadratic program, solved by Gurobi.

The model is built with the matrix API (one ``addMVar`` and one ``setMObjective`` with a sparse
Q), so there is no Python loop over terms. The licence comes from the environment: Gurobi reads
``GRB_LICENSE_FILE`` itself; a WLS licence (``GRB_WLSACCESSID``, ``GRB_WLSSECRET``,
``GRB_LICENSEID``) is passed to the environment from :class:`shared.config.Settings`. Without
either, the pip package's size-limited licence applies: at most 200 variables once the model has
a quadratic term, which is a few pixels of a stereo row.
"""

from __future__ import annotations

from typing import Any

import dimod
import numpy as np

from shared.config import Settings
from shared.solvers.base import (
    Availability,
    SolverError,
    SolverUnavailableError,
    TransientSolverError,
)
from shared.solvers.sampler import Sampler

#: Largest model with quadratic terms the size-limited pip licence accepts.
PIP_LICENCE_VARIABLES = 200
#: The objective is scaled so that its largest coefficient has this size: Gurobi's absolute
#: tolerances otherwise hide differences of ~1e-7 between stereo labellings (MRF energies of a
#: row are ~0.01-1), and it reported "optimal" for a labelling 4e-6 (relative) above the optimum.
OBJECTIVE_SCALE = 100.0
#: Friendly parameter names -> Gurobi parameter names (raw Gurobi names are accepted too).
PARAM_NAMES = {"time_limit": "TimeLimit", "mip_gap": "MIPGap", "threads": "Threads"}

LICENCE_HELP = (
    "configure a full licence: set GRB_LICENSE_FILE to a gurobi.lic file, or a Web License "
    "Service licence with GRB_WLSACCESSID, GRB_WLSSECRET and GRB_LICENSEID"
)


def licence_kind(settings: Settings) -> str:
    """``"wls"``, ``"file"`` or ``"pip"`` (the size-limited licence bundled with gurobipy).

    Parameters
    ----------
    settings : Settings
        Application settings (the ``grb_*`` licence fields).

    Returns
    -------
    str
        ``"wls"`` when all three WLS fields are set, ``"file"`` with a licence file, else ``"pip"``.
    """
    if settings.grb_wls_access_id and settings.grb_wls_secret and settings.grb_license_id:
        return "wls"
    if settings.grb_license_file is not None:
        return "file"
    return "pip"


def _environment(settings: Settings):
    import gurobipy as gp

    env = gp.Env(empty=True)
    env.setParam("OutputFlag", 0)
    access, secret, licence = (
        settings.grb_wls_access_id,
        settings.grb_wls_secret,
        settings.grb_license_id,
    )
    if access and secret and licence:  # licence_kind(settings) == "wls"
        env.setParam("WLSACCESSID", access.get_secret_value())
        env.setParam("WLSSECRET", secret.get_secret_value())
        env.setParam("LICENSEID", licence)
    env.start()
    return env


def _gurobi_params(params: dict[str, Any]) -> dict[str, Any]:
    return {PARAM_NAMES.get(key, key): value for key, value in params.items()}


class GurobiSampler(Sampler, dimod.Initialized):
    """Binary quadratic program with Gurobi (MIQP); parameters ``time_limit`` (s), ``mip_gap``
    (0: prove optimality), ``threads`` (defaults in ``GurobiParams``) or any raw Gurobi
    parameter name. The first of ``initial_states`` is Gurobi's MIP start."""

    name = "gurobi"
    parameters: dict[str, list] = {  # noqa: RUF012 (dimod's interface)
        **{key: [] for key in PARAM_NAMES},
        "seed": [],
        "initial_states": [],
    }
    properties: dict[str, Any] = {}  # noqa: RUF012

    def available(self) -> Availability:
        try:
            import gurobipy  # noqa: F401
        except ImportError:
            return Availability(False, "gurobipy is not installed (pip install 'qhsm[gurobi]')")
        kind = licence_kind(self.settings)
        if kind == "wls":
            return Availability(True, "full licence (Gurobi Web License Service)")
        if kind == "file":
            return Availability(True, "full licence (GRB_LICENSE_FILE)")
        return Availability(
            True,
            f"size-limited pip licence: at most {PIP_LICENCE_VARIABLES} variables with "
            "quadratic terms (set GRB_LICENSE_FILE or GRB_WLSACCESSID/GRB_WLSSECRET/"
            "GRB_LICENSEID for a full licence)",
        )

    def run(self, bqm, params: dict[str, Any], *, seed, initial_states) -> dimod.SampleSet:
        """Minimise the BQM as a binary MIQP (objective scaled to :data:`OBJECTIVE_SCALE`).

        Parameters
        ----------
        bqm : dimod.BinaryQuadraticModel
            The bundle's QUBO, BINARY on 0..n-1 (``Sampler.sample`` converts any other BQM).
        params : dict
            ``time_limit`` (seconds), ``mip_gap``, ``threads`` or raw Gurobi parameter names.
        seed : int or None
            Gurobi's ``Seed`` (taken modulo 2e9).
        initial_states : samples-like or None
            Its first state is the MIP start.

        Returns
        -------
        dimod.SampleSet
            One sample; info has the status, ``optimal``, ``mip_gap``, ``bound``, ``licence``
            and the solver time in seconds.

        Raises
        ------
        TransientSolverError
            When Gurobi stops without any solution.
        SolverError
            For Gurobi errors (``SolverUnavailableError`` without a valid licence).
        """
        import gurobipy as gp
        import scipy.sparse as sp

        settings = self.settings
        start = None
        if initial_states is not None:
            parsed = self.parse_initial_states(bqm, initial_states, num_reads=1)
            start = parsed.initial_states.record.sample[0]
        n = bqm.num_variables
        linear, (rows, cols, quadratic), offset = bqm.to_numpy_vectors(variable_order=range(n))
        largest = max(np.abs(linear).max(initial=0.0), np.abs(quadratic).max(initial=0.0))
        scale = OBJECTIVE_SCALE / largest if largest > 0 else 1.0
        q_matrix = sp.csr_matrix((quadratic * scale, (rows, cols)), shape=(n, n))
        try:
            with _environment(settings) as env, gp.Model(env=env) as model:
                for key, value in _gurobi_params(params).items():
                    model.setParam(key, value)
                if seed is not None:
                    model.setParam("Seed", int(seed) % 2_000_000_000)
                x = model.addMVar(n, vtype=gp.GRB.BINARY)
                model.setMObjective(  # type: ignore[call-overload]  # a sparse Q is accepted
                    q_matrix, linear * scale, float(offset) * scale, sense=gp.GRB.MINIMIZE
                )
                if start is not None:
                    x.Start = np.asarray(start, dtype=float)  # type: ignore[assignment]
                model.optimize()
                status = model.Status
                if model.SolCount == 0:
                    raise TransientSolverError(
                        f"gurobi found no solution (status {status}); raise time_limit"
                    )
                values = np.rint(x.X).astype(np.int8)
                info = {
                    "status": "optimal" if status == gp.GRB.OPTIMAL else f"status {status}",
                    "optimal": status == gp.GRB.OPTIMAL,
                    "mip_gap": float(model.MIPGap),
                    "bound": float(model.ObjBound) / scale,
                    "licence": licence_kind(settings),
                }
                info["timing"] = {"solver": float(model.Runtime)}
        except gp.GurobiError as error:
            raise _translate(error, n, bool(quadratic.size)) from None
        return dimod.SampleSet.from_samples_bqm((values.reshape(1, -1), range(n)), bqm, info=info)


def _translate(error, num_variables: int, quadratic: bool) -> SolverError:
    """Gurobi's errors as our typed errors, with what to do about them."""
    import gurobipy as gp

    if error.errno == gp.GRB.Error.SIZE_LIMIT_EXCEEDED:
        return SolverError(
            f"gurobi: this bundle has {num_variables} variables"
            f"{' with quadratic terms' if quadratic else ''}, more than the size-limited pip "
            f"licence allows (at most {PIP_LICENCE_VARIABLES} variables once the model has "
            f"quadratic terms); use smaller bundles or images, or {LICENCE_HELP}"
        )
    if error.errno == gp.GRB.Error.NO_LICENSE:
        return SolverUnavailableError(f"gurobi: no valid licence ({error.message}); {LICENCE_HELP}")
    return SolverError(f"gurobi failed (error {error.errno}): {error.message}")
