"""The detector: backbone -> a query module per feature level (ROD, skip or TDID) -> a YOLOv3-style
top-down neck -> class-free heads (thesis Fig 5.8-5.9, §5.3.4).

Each head predicts, per grid cell and anchor, ``(t_x, t_y, t_w, t_h, t_o)``; decoding follows
Eq 5.16-5.19: centre ``(σ(t_x) + c_x, σ(t_y) + c_y)`` cells, size ``p·exp(t)`` for anchor prior ``p``.
The layout string names the module at each level from the finest (stride 8, small objects) to the
coarsest (stride 32), as in the thesis's RRR / SSR / RSS labels.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from binpick.detection.backbone import BACKBONES, build_backbone, conv_bn
from binpick.detection.depth import DepthEncoder
from binpick.detection.pickability import PickabilityHead, query_crops
from binpick.detection.ops import cxcywh_to_xyxy, nms
from binpick.detection.rod import RODModule, SkipModule, TDIDModule, crop_features

STRIDES = (8, 16, 32)
ANCHORS_PER_LEVEL = 3
PRE_NMS = 300  # best-scoring boxes per image that go into NMS
MEAN = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
STD = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
# anchor priors (w, h) as fractions of the image side, finest level first; training replaces them
# with k-means clusters of its own boxes
DEFAULT_ANCHORS = ((0.05, 0.05), (0.08, 0.06), (0.06, 0.09), (0.11, 0.11), (0.16, 0.09), (0.09, 0.17),
                   (0.2, 0.2), (0.3, 0.18), (0.18, 0.3))


@contextmanager
def running_statistics(module: nn.Module) -> Iterator[None]:
    """Batch norm on its running statistics inside, and not updating them: for query images (shop
    photos, crops), whose batches look nothing like scenes. In training mode a batch of studio photos
    was normalised by its own statistics, at evaluation by the scenes' running ones, so the photo
    query learnt features it never saw at evaluation: its training loss fell while its val AP50 fell
    from 0.59 to 0.55. Gradients still flow."""
    norms = [m for m in module.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm) and m.training]
    for norm in norms:
        norm.eval()
    try:
        yield
    finally:
        for norm in norms:
            norm.train()


@dataclass(frozen=True)
class ModelSpec:
    backbone: str = "tiny"  # tiny | darknet53
    method: str = "rod"  # rod | tdid
    layout: str = "RRR"  # per level (stride 8, 16, 32): R = ROD module, S = skip (rod only)
    scales: tuple[float, ...] = (0.5, 1.0, 2.0)  # D crop scales of the ROD module
    query: str = "crop"  # crop: the known box in the image (§5.3); photo: a shop photo (§6.3)
    # photo queries: the photo framed on its product and matched at these sides, as fractions of the
    # scene image's side (binpick.detection.photos); empty: the whole photo at the D scales (weights
    # trained before photos were framed)
    photo_sizes: tuple[float, ...] = ()
    depth: bool = False  # also reads the scene's depth (binpick.detection.depth): geometry for pickability
    # a second look at each detection (binpick.detection.pickability): "" none, "rgb" colour, "rgbd" with depth
    pickability: str = ""
    pickability_width: int = 32  # channels of the head's first convolution
    pickability_query: bool = False  # the head also compares each window with the query (other products score low)
    pickability_factorised: bool = False  # ... as two questions: picks it (window alone) x same product (window and query)

    @property
    def reads_depth(self) -> bool:
        """Whether the network needs the scene's depth: its depth encoder or its pickability head."""
        return self.depth or self.pickability == "rgbd"

    @property
    def frames_photos(self) -> bool:
        """Whether photo queries are framed on their product (weights with ``photo_sizes``)."""
        return bool(self.photo_sizes)

    def check(self) -> None:
        from binpick.core.errors import ConfigError

        if self.backbone not in BACKBONES:
            raise ConfigError(f"model.backbone must be one of {', '.join(BACKBONES)}, got {self.backbone!r}")
        if self.method not in ("rod", "tdid"):
            raise ConfigError(f"model.method must be 'rod' or 'tdid', got {self.method!r}")
        if len(self.layout) != 3 or set(self.layout) - {"R", "S"}:
            raise ConfigError(f"model.layout must be three letters of R (ROD) and S (skip), e.g. RRR or SSR, got {self.layout!r}")
        if self.query not in ("crop", "photo"):
            raise ConfigError(f"model.query must be 'crop' or 'photo', got {self.query!r}")
        if not self.scales or any(s <= 0 for s in self.scales):
            raise ConfigError(f"model.scales must be positive numbers, got {list(self.scales)}")
        if self.photo_sizes and (self.query != "photo" or self.method != "rod"):
            raise ConfigError("model.photo_sizes is for ROD with photo queries (model.query: photo, model.method: rod)")
        if not isinstance(self.depth, bool):
            raise ConfigError(f"model.depth must be true or false, got {self.depth!r}")
        if self.pickability not in ("", "rgb", "rgbd"):
            raise ConfigError(f"model.pickability must be '', 'rgb' or 'rgbd', got {self.pickability!r}")
        if not isinstance(self.pickability_query, bool):
            raise ConfigError(f"model.pickability_query must be true or false, got {self.pickability_query!r}")
        if self.pickability_factorised and not self.pickability_query:
            raise ConfigError("model.pickability_factorised needs model.pickability_query: true (its second question is about the query)")
        if any(not 0 < s <= 1 for s in self.photo_sizes):
            raise ConfigError(f"model.photo_sizes must be fractions of the image side in (0, 1], got {list(self.photo_sizes)}")


class DetectorNetwork(nn.Module):
    def __init__(self, spec: ModelSpec, image_size: int, query_size: int = 96) -> None:
        super().__init__()
        spec.check()
        self.spec, self.image_size, self.query_size = spec, image_size, query_size
        self.trained_config: dict = {}  # the run's config, when loaded from a checkpoint
        self.trained_products: list[str] | None = None  # products its training set asked it to find, when known
        self.trained_domains: list[str] = ["default"]  # scene domains of its training data (binpick.sim.domain)
        self.score_threshold: float | None = None  # the score above which its detections are kept, when chosen for it
        self.inference_only = False  # a copy with batch norms folded (for_inference): no training, no saving
        self.backbone = build_backbone(spec.backbone)
        channels = BACKBONES[spec.backbone].channels
        modules = []
        for letter, c in zip(spec.layout, channels):
            if spec.method == "tdid":
                modules.append(TDIDModule(c))
            else:
                modules.append(RODModule(c, spec.scales) if letter == "R" else SkipModule(c))
        self.modules_per_level = nn.ModuleList(modules)
        self.depth_encoder = DepthEncoder(channels) if spec.depth else None
        self.pickability = (PickabilityHead(spec.pickability == "rgbd", spec.pickability_width, spec.pickability_query,
                                            spec.pickability_factorised)
                            if spec.pickability else None)
        c1, c2, c3 = channels
        self.top = nn.Sequential(conv_bn(c3, c3 // 2, 1), conv_bn(c3 // 2, c3, 3), conv_bn(c3, c3 // 2, 1))
        self.lateral3 = conv_bn(c3 // 2, c2 // 2, 1)
        self.middle = nn.Sequential(conv_bn(c2 + c2 // 2, c2 // 2, 1), conv_bn(c2 // 2, c2, 3), conv_bn(c2, c2 // 2, 1))
        self.lateral2 = conv_bn(c2 // 2, c1 // 2, 1)
        self.bottom = nn.Sequential(conv_bn(c1 + c1 // 2, c1 // 2, 1), conv_bn(c1 // 2, c1, 3), conv_bn(c1, c1 // 2, 1))
        self.heads = nn.ModuleList([nn.Sequential(conv_bn(c // 2, c, 3), nn.Conv2d(c, ANCHORS_PER_LEVEL * 5, 1))
                                    for c in channels])
        for head in self.heads:  # start with low objectness everywhere (few cells hold objects)
            nn.init.constant_(head[-1].bias, 0.0)
            head[-1].bias.data[4::5] = -4.0
        self.register_buffer("anchors", torch.tensor(DEFAULT_ANCHORS, dtype=torch.float32).view(3, ANCHORS_PER_LEVEL, 2) * image_size)

    def for_inference(self) -> DetectorNetwork:
        """A copy for prediction only, ~1.2x faster predict at batch 1 on a CPU (binpick.detection.inference):
        batch norms folded into the convolutions, channels-last weights."""
        from binpick.detection.inference import inference_copy

        return inference_copy(self)

    def train(self, mode: bool = True) -> DetectorNetwork:
        if mode and self.inference_only:
            raise RuntimeError("this is an inference copy of a detector (its batch norms are folded): train the network it was made from")
        return super().train(mode)

    # ------------------------------------------------------------------ forward
    def features(self, images: torch.Tensor) -> list[torch.Tensor]:
        return self.backbone((images - MEAN.to(images)) / STD.to(images))

    def query_features(self, scene: list[torch.Tensor], query_boxes: torch.Tensor | None,
                       query_images: torch.Tensor | None) -> list[list[torch.Tensor]]:
        """Per level, per sample: the query's features. ROD with a box crops the scene's own features
        (Eq 5.11); TDID and photo queries run the query image through the same backbone."""
        # unbind, not level[b]: each indexing's backward pass allocates the whole batch's gradient
        if self.spec.method == "rod" and self.spec.query == "crop":
            return [[crop_features(sample, box, stride) for sample, box in zip(level.unbind(0), query_boxes)]
                    for level, stride in zip(scene, STRIDES)]
        with running_statistics(self.backbone):
            if self.spec.photo_sizes:  # one kernel per photo size, in place of the D scales of one crop
                sized = (query_images if isinstance(query_images, (list, tuple))
                         else self.sized_photos(query_images, int(scene[0].shape[-1]) * STRIDES[0]))
                per_size = [self.features(photo) for photo in sized]
                return [list(zip(*(level.unbind(0) for level in levels))) for levels in zip(*per_size)]
            query = self.features(query_images)
        return [list(level.unbind(0)) for level in query]

    def photo_sides(self, scene_side: int) -> list[int]:
        """The sides, in pixels, a shop photo is shrunk to for a scene ``scene_side`` pixels wide."""
        return [max(16, round(f * scene_side)) for f in self.spec.photo_sizes]

    def sized_photos(self, query_images: torch.Tensor, scene_side: int) -> list[torch.Tensor]:
        """The query photos at each of :meth:`photo_sides` (antialiased: kept outside an exported graph,
        which takes them as inputs, as ONNX's resize does not antialias the same way)."""
        return [F.interpolate(query_images, size=(s, s), mode="bilinear", align_corners=False, antialias=True)
                for s in self.photo_sides(scene_side)]

    def forward(self, images: torch.Tensor, query_boxes: torch.Tensor | None = None,
                query_images: torch.Tensor | None = None, depth: torch.Tensor | None = None) -> dict[str, list]:
        """``depth``: (B, 1, H, W) height maps (:func:`binpick.detection.depth.depth_input`), for
        detectors that read depth (``spec.depth``). ``query_images`` of a model with ``photo_sizes``
        may also come already sized (:meth:`sized_photos`)."""
        scene = self.features(images)
        queries = self.query_features(scene, query_boxes, query_images)
        fused, heatmaps = [], []
        for module, level, query in zip(self.modules_per_level, scene, queries):
            out, heatmap = module(level, query)
            fused.append(out)
            heatmaps.append(heatmap)
        if self.depth_encoder is not None:
            if depth is None:
                from binpick.core.errors import ConfigError

                raise ConfigError("this detector reads depth as well as colour: give the scene's depth image")
            fused = [f + g.to(f.dtype) for f, g in zip(fused, self.depth_encoder(depth.to(images.dtype)))]
        p3 = self.top(fused[2])
        p2 = self.middle(torch.cat([fused[1], F.interpolate(self.lateral3(p3), scale_factor=2.0)], 1))
        p1 = self.bottom(torch.cat([fused[0], F.interpolate(self.lateral2(p2), scale_factor=2.0)], 1))
        raw = [head(p) for head, p in zip(self.heads, (p1, p2, p3))]
        return {"raw": [r.view(r.shape[0], ANCHORS_PER_LEVEL, 5, r.shape[2], r.shape[3]) for r in raw],
                "heatmaps": heatmaps}

    # ------------------------------------------------------------------ decoding
    def decode(self, raw: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Eq 5.16-5.19 for every cell and anchor of every level: boxes (B, N, 4) xyxy pixels and
        objectness (B, N)."""
        boxes, scores = [], []
        for level, (r, stride) in enumerate(zip(raw, STRIDES)):
            b, a, _, h, w = r.shape
            ys, xs = torch.meshgrid(torch.arange(h, device=r.device), torch.arange(w, device=r.device), indexing="ij")
            cx = (torch.sigmoid(r[:, :, 0]) + xs) * stride
            cy = (torch.sigmoid(r[:, :, 1]) + ys) * stride
            anchors = self.anchors[level].view(1, a, 2, 1, 1)
            bw = anchors[:, :, 0] * torch.exp(r[:, :, 2].clamp(max=6.0))
            bh = anchors[:, :, 1] * torch.exp(r[:, :, 3].clamp(max=6.0))
            boxes.append(cxcywh_to_xyxy(torch.stack([cx, cy, bw, bh], -1)).reshape(b, -1, 4))
            scores.append(torch.sigmoid(r[:, :, 4]).reshape(b, -1))
        return torch.cat(boxes, 1), torch.cat(scores, 1)

    @torch.no_grad()
    def detect(self, images: torch.Tensor, query_boxes: torch.Tensor | None = None, query_images: torch.Tensor | None = None,
               score_threshold: float = 0.01, iou_threshold: float = 0.45, max_detections: int = 100,
               depth: torch.Tensor | None = None) -> tuple[list[dict[str, torch.Tensor]], list]:
        """Boxes and scores after NMS, per image, plus the heatmaps (for pictures like Fig 6.11)."""
        out = self.forward(images, query_boxes, query_images, depth)
        boxes, scores = (v.float().cpu() for v in self.decode(out["raw"]))  # NMS is sequential: on the CPU
        results = self.select(boxes, scores, score_threshold, iou_threshold, max_detections)
        if self.pickability is not None:
            results = self.rescore(images, depth, results, query_boxes, query_images)
        return results, out["heatmaps"]

    def select(self, boxes: torch.Tensor, scores: torch.Tensor, score_threshold: float, iou_threshold: float,
               max_detections: int) -> list[dict[str, torch.Tensor]]:
        """Decoded boxes (B, N, 4) and scores (B, N) -> per image, those above the threshold after NMS."""
        results = []
        for b in range(boxes.shape[0]):
            keep = scores[b] > score_threshold
            kept_boxes = boxes[b][keep].clamp(0, self.image_size)
            kept_scores = scores[b][keep]
            best = kept_scores.argsort(descending=True)[:PRE_NMS]  # NMS is quadratic
            kept_boxes, kept_scores = kept_boxes[best], kept_scores[best]
            order = nms(kept_boxes, kept_scores, iou_threshold)[:max_detections]
            results.append({"boxes": kept_boxes[order], "scores": kept_scores[order]})
        return results

    def without_pickability(self) -> DetectorNetwork:
        """This network with its pickability head switched off (the same module objects, shared):
        the detector's own ranking, and no depth needed unless its features read depth."""
        import copy
        from dataclasses import replace

        plain = copy.copy(self)
        plain._modules = dict(self._modules)  # nn.Module keeps children here: a copy of the dict, not of them
        plain.pickability = None
        plain.spec = replace(self.spec, pickability="", pickability_query=False, pickability_factorised=False)
        return plain

    def rescore(self, images: torch.Tensor, depth: torch.Tensor | None, results: list[dict[str, torch.Tensor]],
                query_boxes: torch.Tensor | None = None, query_images: torch.Tensor | None = None) -> list[dict[str, torch.Tensor]]:
        """Each detection's score times the pickability head's probability that the policy picks that
        copy, best first. Every detection stays: the head re-ranks, the detector's threshold decides
        what was found (a copy the head doubts still counts towards recall; dropping those products
        under the threshold cost 0.01 AP50 on the seen val tasks)."""
        if self.spec.pickability == "rgbd" and depth is None:
            from binpick.core.errors import ConfigError

            raise ConfigError("this detector's pickability head reads depth: give the scene's depth image")
        queries = None
        if self.spec.pickability_query:
            queries = query_crops(images, query_boxes, query_images if self.spec.query == "photo" else None)
        probabilities = self.pickability.probabilities(images, depth, [r["boxes"].to(images.device) for r in results], queries)
        rescored = []
        for result, p in zip(results, probabilities):
            scores = result["scores"] * p
            order = scores.argsort(descending=True)
            rescored.append({"boxes": result["boxes"][order], "scores": scores[order]})
        return rescored
