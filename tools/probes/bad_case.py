"""Class ``bad-case``: bad values through ``--set`` are refused in one line naming the key, status 2,
and nothing is written."""

from __future__ import annotations

from . import CASES, ok, probe, wrong

BAR = CASES / "impacting_bar.yaml"
BLOCK = CASES / "sliding_block.yaml"

BAD_SETS = [
    (BAR, "solver.dt=-1", "solver.dt"),
    (BAR, "solver.dt=abc", "solver.dt"),
    (BAR, "solver.t_end=0", "solver.t_end"),
    (BAR, "material.E=-1", "material.E"),
    (BAR, "material.rho=0", "material.rho"),
    (BAR, "mesh.cells=0", "mesh.cells"),
    (BAR, "mesh.cells=2.5", "mesh.cells"),
    (BAR, "contacts.0.restitution=1.5", "restitution"),
    (BAR, "contacts.0.nodes=nowhere", "nowhere"),
    (BAR, "solver.method=nonsense", "solver.method"),
    (BLOCK, "contacts.0.friction=-0.1", "friction"),
    (BLOCK, "parameters.g=[1,2]", "g"),
    (BLOCK, "loads.0.acceleration=[0,0,0,0]", "acceleration"),
    (BLOCK, "material.E=&a [*a]", "material.E"),
]


def _bad_set(case, setting, needle):
    def body(ctx):
        out = ctx.folder / "out"
        r = ctx.run("run", case, "-q", "-o", out, "--set", setting)
        verdict = ctx.refused(r, needle)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


for _case, _setting, _needle in BAD_SETS:
    probe("bad-case", f"{_case.stem} --set {_setting}")(_bad_set(_case, _setting, _needle))


@probe("bad-case", "a case file that is not YAML")
def _not_yaml(ctx):
    case = ctx.folder / "broken.yaml"
    case.write_text("mesh: {shape: bar\nsolver: [\n")
    return ctx.refused(ctx.run("run", case, "-q", "-o", ctx.folder / "out"), "broken.yaml")


@probe("bad-case", "a case file that does not exist")
def _missing(ctx):
    r = ctx.run("run", ctx.folder / "none.yaml", "-q", "-o", ctx.folder / "out")
    verdict = ctx.refused(r, "none.yaml")
    return verdict if verdict.kind != "ok" else ok()
