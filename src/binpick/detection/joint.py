"""Several detectors trained on the very same batches (the rows of one comparison table)."""

from __future__ import annotations

from typing import Any

from binpick.detection.train import DetectorTrainer
from binpick.detection.training_data import loader
from binpick.core.errors import ConfigError
from binpick.core.runs import SILENT, RunCallback


class JointTraining:
    """Several detectors trained on the very same batches: one loader (the costly part on a CPU, and
    the bottleneck beside a GPU) feeds every model, so rows compared in a table (ROD, ROD without
    L_h, TDID, the photo query, two backbones) share data, order, augmentation, budget and seed by
    construction. Every trainer keeps its own run folder, checkpoints and early stopping."""

    def __init__(self, trainers: list[DetectorTrainer]) -> None:
        if not trainers:
            raise ConfigError("joint training needs at least one detector")
        first = trainers[0].config
        for trainer in trainers[1:]:
            if trainer.config.data != first.data or trainer.config.train.batch_size != first.train.batch_size:
                raise ConfigError(f"{trainer.config.name}: joint training needs the same data section and batch size as {first.name}")
        if first.data.rehearse:
            raise ConfigError(f"{first.name}: data.rehearse is for one detector's fine-tuning, not joint training")
        self.trainers = trainers
        self.train_set = trainers[0].train_set
        self.train_set.with_photo = any(t.model.spec.query == "photo" for t in trainers)
        framing = {t.model.spec.frames_photos for t in trainers if t.model.spec.query == "photo"}
        if len(framing) > 1:
            raise ConfigError("joint training needs every photo-query row to frame its photos alike (model.photo_sizes)")
        self.train_set.frame_photos = framing == {True}
        if any(t.model.spec.depth for t in trainers):  # the others ignore it
            self.train_set.add_depth()

    def run(self, callback: RunCallback = SILENT) -> dict[str, dict[str, Any]]:
        import time

        first = self.trainers[0]
        config = first.config
        active = list(self.trainers)
        started = time.monotonic()
        for trainer in active:
            trainer.open_writer(started)  # one time budget for all rows
        try:
            with callback.task("joint training", first.total_steps, first.step) as task:
                while active and first.epoch < config.train.epochs:
                    epoch = first.epoch
                    self.train_set.set_epoch(epoch)
                    sums = {id(t): {} for t in active}
                    for trainer in active:
                        trainer.model.train()
                    for batch in loader(self.train_set, config.train.batch_size, True, config.train.workers, config.train.seed + epoch):
                        for trainer in active:
                            trainer.note_time(time.monotonic() - started)
                            trainer.train_step(batch, sums[id(trainer)])
                        task.update(first.step, status=f"epoch {epoch + 1}/{config.train.epochs} " +
                                    " ".join(f"{t.config.name}{t.status_text}" for t in active))
                        if first.out_of_time(time.monotonic() - started):
                            break
                    ended = time.monotonic()  # every row judges the time budget at the same moment
                    for trainer in active:
                        trainer.epoch_ended = ended
                    active = [t for t in active if not t.end_epoch(t.epoch_figures(sums[id(t)]))]
                    for trainer in self.trainers:
                        trainer.epoch_ended = None
                    first = active[0] if active else first
        finally:
            for trainer in self.trainers:
                if trainer.writer is not None:
                    trainer.writer.close()
        return {trainer.config.name: trainer.finish() for trainer in self.trainers}
