"""The plan's tasks on dask: the Tables and refits, a consistent joint refit adding its Table."""
from __future__ import annotations

from incipient_slip.cluster import open_client

from .planning import Plan
from .spec import POINTS, slug
from .tasks import point_task, refit_task


def execute(p: Plan, settings) -> tuple[dict, dict, dict]:
    """Run the plan's tasks on dask; return the one-at-a-time Tables, the joint Tables and the joint
    refits without a Table, each {point: result}."""
    from dask.distributed import as_completed

    def table_future(name, overrides, fit=None):
        sweep = p.sweep_of(name)
        return client.submit(point_task, name, overrides, p.runs, p.n_series, p.steps, settings.seed, str(p.work),
                             sweep, p.refits, fit, str(settings.figures) if settings.figures else None,
                             p.rig_points.get(name), p.rig_materials,
                             key=f"validation-{slug(name)}-{settings.seed}-sweep{sweep}",
                             pure=False)

    done, joint_done, refit_only = {}, {}, {}
    with open_client(p.scheduler, p.workers) as client:
        # the longest tasks first (a point whose friction limit lags runs one label row more), so
        # that the last task to finish is a short one
        names = sorted(p.names, key=lambda n: -float(POINTS.get(n, {}).get("stick_slip.friction_limit_lag_s", 0.0)))
        futures = ([table_future(n, POINTS.get(n, {})) for n in names]
                   + [table_future(n, p.grid[n]) for n in p.sweep_at])
        futures += [client.submit(refit_task, n, ov, settings.seed, p.refits,
                                  key=f"refit-{slug(n)}-{settings.seed}", pure=False)
                    for n, ov in (p.grid.items() if p.joint else ()) if n not in p.sweep_at]
        total, i = len(futures), 0
        queue = as_completed(futures)
        for fut in queue:     # a consistent joint refit adds its Table to the queue
            res, i = fut.result(), i + 1
            verdict = {True: "consistent", False: "INCONSISTENT", None: "the identified rig's values, not refitted"}[
                res["consistent"]]
            if "runs" not in res:
                refit_only[res["point"]] = res
                if res["consistent"]:     # (a --sweep-at point has its Table with the sweep already)
                    queue.add(table_future(res["point"], res["overrides"], res))
                    total += 1
            elif res["point"] in p.grid:
                joint_done[res["point"]] = res
            else:
                done[res["point"]] = res
            if settings.progress:
                what = "refit" if "runs" not in res else "Table"
                print(f"  [{i}/{total}] {what} of {res['point']!r} done in {res['seconds']:.0f} s "
                      f"({verdict} with T1-T4', T7)", flush=True)
    return done, joint_done, refit_only
