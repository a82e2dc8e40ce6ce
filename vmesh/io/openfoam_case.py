"""The solver part of an OpenFOAM case written by ``vmesh export --format openfoam --case``:
``0/U``, ``0/p``, ``constant/`` fluid properties and ``system/`` for ``simpleFoam``
(steady) or ``pimpleFoam`` (transient), laminar, incompressible.

Boundary conditions: every patch named ``inlet*`` gets a uniform velocity normal to it
(``surfaceNormalFixedValue``, into the vessel) and ``zeroGradient`` pressure; the ``wall``
``noSlip``; every other patch (the outlets) ``zeroGradient`` velocity and fixed pressure 0.
Pressure is kinematic (p / rho, m²/s²), as in OpenFOAM's incompressible solvers. The
dictionaries are those of OpenFOAM v1912+ (ESI, Debian's ``openfoam``); Foundation
releases read ``constant/physicalProperties`` and ``momentumTransport``, written as well.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Kinematic viscosity of blood (m²/s): 3.5e-3 Pa·s / 1060 kg/m³.
BLOOD_NU = 3.3e-6


@dataclass(frozen=True)
class FlowCase:
    """What the case simulates (SI units).

    Attributes
    ----------
    kind : str
        ``"steady"`` (simpleFoam) or ``"transient"`` (pimpleFoam).
    inlet_velocity : float
        Speed normal to every inlet patch, m/s.
    nu : float
        Kinematic viscosity, m²/s.
    iterations : int
        simpleFoam iterations (steady; stops earlier when the residuals fall below 1e-5).
    end_time, time_step : float
        pimpleFoam end time and first time step, s (the step adapts to Courant number 0.9).
    """

    kind: str = "steady"
    inlet_velocity: float = 0.1
    nu: float = BLOOD_NU
    iterations: int = 1000
    end_time: float = 1.0
    time_step: float = 1e-4


_FV_SCHEMES = """ddtSchemes
{{
    default         {ddt};
}}

gradSchemes
{{
    default         Gauss linear;
    grad(U)         cellLimited Gauss linear 1;
}}

divSchemes
{{
    default         none;
    div(phi,U)      {div_u};
    div((nuEff*dev2(T(grad(U))))) Gauss linear;
}}

laplacianSchemes
{{
    default         Gauss linear limited corrected 0.5;
}}

interpolationSchemes
{{
    default         linear;
}}

snGradSchemes
{{
    default         limited corrected 0.5;
}}
"""

_SOLVERS = """solvers
{{
    "p|pFinal"
    {{
        solver          GAMG;
        smoother        GaussSeidel;
        tolerance       1e-7;
        relTol          {p_rel};
    }}
    "U|UFinal"
    {{
        solver          smoothSolver;
        smoother        symGaussSeidel;
        tolerance       1e-8;
        relTol          {u_rel};
    }}
}}
"""


def _patch_kind(name: str) -> str:
    return "wall" if name == "wall" else ("inlet" if name.lower().startswith("inlet") else "outlet")


def field_U(patches, inlet_velocity: float) -> str:
    body = ["dimensions      [0 1 -1 0 0 0 0];\n\ninternalField   uniform (0 0 0);\n\nboundaryField\n{\n"]
    for name in patches:
        kind = _patch_kind(name)
        if kind == "wall":
            bc = "type            noSlip;"
        elif kind == "inlet":
            # refValue along the outward normal: negative flows into the vessel
            bc = f"type            surfaceNormalFixedValue;\n        refValue        uniform {-inlet_velocity:.9g};"
        else:
            bc = "type            zeroGradient;"
        body.append(f"    {name}\n    {{\n        {bc}\n    }}\n")
    body.append("}\n")
    return "".join(body)


def field_p(patches) -> str:
    body = ["dimensions      [0 2 -2 0 0 0 0];\n\ninternalField   uniform 0;\n\nboundaryField\n{\n"]
    for name in patches:
        bc = "type            fixedValue;\n        value           uniform 0;" if _patch_kind(name) == "outlet" else "type            zeroGradient;"
        body.append(f"    {name}\n    {{\n        {bc}\n    }}\n")
    body.append("}\n")
    return "".join(body)


def case_files(flow: FlowCase, patches, units_note: str) -> dict:
    """``{relative path: (class, body)}`` of the solver dictionaries of ``flow``."""
    steady = flow.kind == "steady"
    app = "simpleFoam" if steady else "pimpleFoam"
    nu = f"{flow.nu:.9g}"
    has_outlet = any(_patch_kind(n) == "outlet" for n in patches)
    if steady:
        control = (
            f"application     {app};\nstartFrom       startTime;\nstartTime       0;\nstopAt          endTime;\n"
            f"endTime         {flow.iterations};\ndeltaT          1;\nwriteControl    timeStep;\nwriteInterval   {max(flow.iterations, 1)};\n"
            "purgeWrite      0;\nwriteFormat     ascii;\nwritePrecision  8;\ntimeFormat      general;\nrunTimeModifiable true;\n"
        )
        algorithm = (
            "SIMPLE\n{\n    nNonOrthogonalCorrectors 1;\n    consistent      no;\n"
            + ("" if has_outlet else "    pRefCell        0;\n    pRefValue       0;\n")
            + "    residualControl\n    {\n        p               1e-5;\n        U               1e-6;\n    }\n}\n\n"
            "relaxationFactors\n{\n    fields\n    {\n        p               0.3;\n    }\n    equations\n    {\n        U               0.7;\n    }\n}\n"
        )
        schemes = _FV_SCHEMES.format(ddt="steadyState", div_u="bounded Gauss linearUpwind grad(U)")
        solvers = _SOLVERS.format(p_rel="0.05", u_rel="0.1")
    else:
        control = (
            f"application     {app};\nstartFrom       startTime;\nstartTime       0;\nstopAt          endTime;\n"
            f"endTime         {flow.end_time:.9g};\ndeltaT          {flow.time_step:.9g};\nadjustTimeStep  yes;\nmaxCo           0.9;\n"
            f"writeControl    adjustableRunTime;\nwriteInterval   {flow.end_time / 10:.9g};\npurgeWrite      0;\nwriteFormat     ascii;\n"
            "writePrecision  8;\ntimeFormat      general;\nrunTimeModifiable true;\n"
        )
        algorithm = (
            "PIMPLE\n{\n    nOuterCorrectors 1;\n    nCorrectors     2;\n    nNonOrthogonalCorrectors 1;\n"
            + ("" if has_outlet else "    pRefCell        0;\n    pRefValue       0;\n")
            + "}\n"
        )
        schemes = _FV_SCHEMES.format(ddt="backward", div_u="Gauss linearUpwind grad(U)")
        solvers = _SOLVERS.format(p_rel="0", u_rel="0")
    return {
        "0/U": ("volVectorField", field_U(patches, flow.inlet_velocity)),
        "0/p": ("volScalarField", field_p(patches)),
        "constant/transportProperties": ("dictionary", f"transportModel  Newtonian;\n\nnu              [0 2 -1 0 0 0 0] {nu};\n"),
        "constant/physicalProperties": ("dictionary", f"viscosityModel  constant;\n\nnu              [0 2 -1 0 0 0 0] {nu};\n"),
        "constant/turbulenceProperties": ("dictionary", "simulationType  laminar;\n"),
        "constant/momentumTransport": ("dictionary", "simulationType  laminar;\n"),
        "system/controlDict": ("dictionary", f"// {units_note}\n" + control),
        "system/fvSchemes": ("dictionary", schemes),
        "system/fvSolution": ("dictionary", solvers + "\n" + algorithm),
    }
