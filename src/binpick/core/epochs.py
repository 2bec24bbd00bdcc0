"""The epoch loop every supervised job shares: train an epoch, evaluate, log, keep the best, checkpoint.

A trainer that inherits :class:`EpochTrainer` says what one epoch of training is
(:meth:`~EpochTrainer.train_epoch`), how the model is judged after it (:meth:`~EpochTrainer.evaluate`,
whose ``metric`` picks the best epoch, higher being better), how the best model is saved and how its
whole state is committed to a checkpoint; the loop does the rest in one place: the progress bar, the
per-epoch history, TensorBoard scalars, the best epoch, and the rule that in a data-parallel group
(:mod:`binpick.core.data_parallel`) every rank trains and rank 0 alone evaluates and writes. A run
resumed from its last checkpoint (``epoch``, ``best``, ``history`` restored by the trainer) goes on
at the next epoch, so an interrupted run ends where the uninterrupted one does. A trainer may also
count its progress finer than epochs (:meth:`~EpochTrainer.progress`; ``self.task`` is the bar while an
epoch trains), evaluate only some epochs (:meth:`~EpochTrainer.evaluate` returns nothing on the others)
and stop early (:meth:`~EpochTrainer.stop_after`, decided on rank 0 and followed by every rank).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from binpick.core.runs import RunCallback


class EpochTrainer:
    """A supervised job's epoch loop (:meth:`run_epochs`). The trainer sets ``run_dir``, ``group``
    (its data-parallel group, or one alone) and, new or resumed, ``epoch``, ``best`` and ``history``."""

    metric = "val_auc"  # the evaluation figure that picks the best epoch (higher is better)
    unset = -0.5  # what an epoch whose metric is None (one class in val) counts as: only the first such is kept
    scalars = {"loss": "train/loss", "val_auc": "val/roc_auc"}  # row key -> TensorBoard tag
    label = "val AUC"  # the metric's name on the progress bar

    run_dir: Path
    epoch: int
    best: float
    history: list[dict[str, Any]]

    def train_epoch(self) -> dict[str, Any]:
        """One epoch on this rank's part of each batch; its figures (``{"loss": ...}``)."""
        raise NotImplementedError

    def evaluate(self) -> dict[str, Any]:
        """The model after an epoch (rank 0 only): figures including :attr:`metric`."""
        raise NotImplementedError

    def save_best(self, row: dict[str, Any]) -> None:
        """Keep the model of the epoch ``row`` describes as the best so far."""
        raise NotImplementedError

    def checkpoint(self) -> None:
        """Commit the whole state (model, optimiser, ``epoch``, ``best``, ``history``) atomically."""
        raise NotImplementedError

    def recorded(self, row: dict[str, Any]) -> dict[str, Any] | None:
        """An epoch's row as the history keeps it (the best epoch is chosen on the row itself); None: none."""
        return row

    def stop_after(self, row: dict[str, Any] | None) -> bool:
        """Whether training ends after the epoch ``row`` describes (None on ranks other than 0): early
        stopping, a time limit. Rank 0's answer is every rank's."""
        return False

    def progress(self, epochs: int) -> tuple[int, int]:
        """The progress bar's ``(total, done)``: epochs, unless the trainer counts finer (steps)."""
        return epochs, self.epoch

    def status(self, row: dict[str, Any]) -> str:
        """The progress bar's line after an epoch."""
        value = row.get(self.metric)
        return f"loss {row['loss']:.3f} {self.label} {value if value is None else round(value, 3)}"

    def open_writer(self) -> None:
        """TensorBoard on rank 0 (``self.writer``; None on the others) before the first epoch."""
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(str(self.run_dir / "tb")) if self.group.lead else None
        self.task = None

    def end_epoch(self, trained: dict[str, Any]) -> bool:
        """After an epoch's training (``trained``: its figures): on rank 0 the epoch is evaluated, recorded,
        logged to TensorBoard, kept if best and checkpointed; True when every rank stops here."""
        self.epoch += 1
        row = None
        if self.group.lead:  # rank 0 evaluates and writes; the others go on to the next epoch
            row = {"epoch": self.epoch, **trained, **self.evaluate()}
            recorded = self.recorded(row)
            if recorded is not None:  # (a trainer that keeps finer rows of its own records none per epoch)
                self.history.append(recorded)
            for key, tag in self.scalars.items():
                if row.get(key) is not None:
                    self.writer.add_scalar(tag, row[key], self.epoch)
            value = row.get(self.metric)
            if (value if value is not None else self.unset) > self.best:
                self.best = value if value is not None else self.unset
                self.save_best(row)
            self.checkpoint()
            status = self.status(row)
            if self.task is not None:  # (a trainer driven by another loop, as in joint training, has none)
                self.task.update(self.progress(self._epochs)[1], status=status)
        return self.group.agree(self.stop_after(row))

    def run_epochs(self, callback: RunCallback, title: str, epochs: int) -> None:
        """Train from ``epoch`` to ``epochs`` (or until :meth:`stop_after` says so), one progress bar."""
        self.open_writer()
        self._epochs = epochs
        try:
            total, done = self.progress(epochs)
            with callback.task(title, total, done) as task:
                self.task = task
                while self.epoch < epochs:
                    if self.end_epoch(self.train_epoch()):
                        break
        finally:
            if self.writer is not None:
                self.writer.close()
