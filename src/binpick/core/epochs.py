"""The epoch loop every supervised job shares: train an epoch, evaluate, log, keep the best, checkpoint.

A trainer that inherits :class:`EpochTrainer` says what one epoch of training is
(:meth:`~EpochTrainer.train_epoch`), how the model is judged after it (:meth:`~EpochTrainer.evaluate`,
whose ``metric`` picks the best epoch, higher being better), how the best model is saved and how its
whole state is committed to a checkpoint; the loop does the rest in one place: the progress bar, the
per-epoch history, TensorBoard scalars, the best epoch, and the rule that in a data-parallel group
(:mod:`binpick.core.data_parallel`) every rank trains and rank 0 alone evaluates and writes. A run
resumed from its last checkpoint (``epoch``, ``best``, ``history`` restored by the trainer) goes on
at the next epoch, so an interrupted run ends where the uninterrupted one does.
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

    def recorded(self, row: dict[str, Any]) -> dict[str, Any]:
        """An epoch's row as the history keeps it (the best epoch is chosen on the row itself)."""
        return row

    def status(self, row: dict[str, Any]) -> str:
        """The progress bar's line after an epoch."""
        value = row.get(self.metric)
        return f"loss {row['loss']:.3f} {self.label} {value if value is None else round(value, 3)}"

    def run_epochs(self, callback: RunCallback, title: str, epochs: int) -> None:
        """Train from ``epoch`` to ``epochs``; on rank 0 each epoch is evaluated, logged to TensorBoard,
        kept if best, checkpointed."""
        from torch.utils.tensorboard import SummaryWriter

        lead = self.group.lead
        writer = SummaryWriter(str(self.run_dir / "tb")) if lead else None
        try:
            with callback.task(title, epochs, self.epoch) as task:
                while self.epoch < epochs:
                    trained = self.train_epoch()
                    self.epoch += 1
                    if not lead:  # rank 0 evaluates and writes; the others go on to the next epoch
                        continue
                    row = {"epoch": self.epoch, **trained, **self.evaluate()}
                    self.history.append(self.recorded(row))
                    for key, tag in self.scalars.items():
                        if row.get(key) is not None:
                            writer.add_scalar(tag, row[key], self.epoch)
                    value = row.get(self.metric)
                    if (value if value is not None else self.unset) > self.best:
                        self.best = value if value is not None else self.unset
                        self.save_best(row)
                    self.checkpoint()
                    task.update(self.epoch, status=self.status(row))
        finally:
            if writer is not None:
                writer.close()
