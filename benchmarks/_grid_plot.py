"""The sbibm grid as a figure: C2ST against the simulation budget, one panel per task, ours
(mean ± sd over the cell's observations, as the table) beside sbibm's published NPE and SNPE.

Hollow markers: a cell run with other settings than `config_for` gives now (the table's †);
``n=k`` beside a marker: a cell with fewer than 10 observations so far.
"""

from matplotlib.figure import Figure

_STYLE = {"npe": ("C0", "o"), "apt": ("C1", "s"), "tsnpe": ("C2", "D"), "fmpe": ("C3", "^")}
_PUBLISHED = {"npe": ("sbibm NPE", "--"), "apt": ("sbibm SNPE", ":")}


def _panel(ax, task, by, stale, published, budgets, methods):
    for m in methods:
        color, marker = _STYLE.get(m, ("C4", "v"))
        shift = 1.0 + 0.1 * (methods.index(m) - (len(methods) - 1) / 2)  # side by side on log x
        cells = [(b, by[(task, m, b)]) for b in budgets if (task, m, b) in by]
        if not cells:
            continue
        xs = [b * shift for b, _ in cells]
        ax.plot(xs, [c["c2st_mean"] for _, c in cells], color=color, lw=1, alpha=0.6)
        for x, (b, c) in zip(xs, cells):
            hollow = (task, m, b) in stale
            ax.errorbar(
                x,
                c["c2st_mean"],
                yerr=c["c2st_sd"],
                color=color,
                marker=marker,
                ms=6,
                capsize=2,
                mfc="white" if hollow else color,
                label=m if b == cells[0][0] else None,
            )
            if c["n_obs"] < 10:
                ax.annotate(
                    f"n={c['n_obs']}",
                    (x, c["c2st_mean"]),
                    xytext=(4, 4),
                    textcoords="offset points",
                    fontsize=7,
                    color=color,
                )
    for m, (label, ls) in _PUBLISHED.items():
        if (task, m) in published:
            ax.plot(budgets, published[(task, m)], color="k", ls=ls, lw=1.2, label=label)
    ax.set_xscale("log")
    ax.set_xticks(budgets, [f"$10^{len(str(b)) - 1}$" for b in budgets])
    ax.set_title(task, fontsize=10)
    ax.set_xlabel("simulations")
    ax.grid(alpha=0.3)


def plot_grid(path, results, published, budgets, tasks, stale):
    """Write the grid's figure to ``path`` (PNG).

    Args:
        results: the stored cells (``task``, ``method``, ``budget``, ``c2st_mean``, ``c2st_sd``,
            ``n_obs``).
        published: ``{(task, method): (C2ST at each budget)}``; only NPE and APT (SNPE) are drawn.
        stale: the ``(task, method, budget)`` keys run with other settings than now (hollow).
    """
    by = {(r["task"], r["method"], r["budget"]): r for r in results}
    methods = ["npe", "apt"] + sorted({r["method"] for r in results} - {"npe", "apt"})
    fig = Figure(figsize=(3.2 * len(tasks), 3.4), layout="constrained")
    axes = fig.subplots(1, len(tasks), sharey=True, squeeze=False)[0]
    for ax, task in zip(axes, tasks):
        _panel(ax, task, by, stale, published, list(budgets), methods)
    axes[0].set_ylabel("C2ST (0.5 = indistinguishable)")
    axes[0].set_ylim(0.48, 1.0)
    labelled = {}  # every series once, wherever it first appears (fmpe has no cell in some panels)
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            labelled.setdefault(label, handle)
    fig.legend(labelled.values(), labelled.keys(), fontsize=8, loc="outside right upper")
    fig.suptitle(
        "sbibm tasks, observations 1-10: ours (mean ± sd) against sbibm's published figures\n"
        "hollow: run with other settings than now (†); n=k: a cell with k < 10 observations so far",
        fontsize=9,
    )
    fig.savefig(path, dpi=110)
