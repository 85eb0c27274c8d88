"""Progress bars for `identify`: per round, the simulations, then the training epochs."""

from __future__ import annotations


class Bars:
    """tqdm bars per round: simulations, then training epochs with the validation loss.

    The methods are `vdsbi.inference.Execution`'s callbacks (`on_simulate`, `on_epoch_end`, and
    `round_end` from `on_round_end`); with `enabled=False` they do nothing.
    """

    def __init__(self, rounds: int, enabled: bool):
        self.rounds, self.enabled, self.bar, self.r = rounds, enabled, None, -1

    def _close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def simulate(self, n: int):
        if not self.enabled:
            return
        from tqdm.auto import tqdm

        self._close()
        self.r += 1
        self.bar = tqdm(total=n, desc=f"round {self.r + 1}/{self.rounds} simulate", unit="sim", leave=True)

    def simulated(self):
        if self.enabled and self.bar is not None:
            self.bar.update(self.bar.total - self.bar.n)
            self._close()

    def epoch(self, r, epoch, train_loss, val_loss):
        if not self.enabled:
            return
        from tqdm.auto import tqdm

        if self.bar is not None and self.bar.desc.endswith("simulate"):
            self.simulated()
        if self.bar is None:
            self.bar = tqdm(desc=f"round {r + 1}/{self.rounds} train", unit="epoch", leave=True)
        self.bar.update(1)
        self.bar.set_postfix(val_loss=f"{val_loss:.3f}")

    def round_end(self, state):
        self._close()
        self.r = state.round - 1

    def close(self):
        self._close()
