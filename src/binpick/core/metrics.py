"""Scores shared by the learnt parts that rank things (grasp quality, pickability)."""

from __future__ import annotations

import numpy as np


def roc_auc(labels: np.ndarray, scores: np.ndarray) -> float | None:
    """Area under the ROC curve: the chance that a random positive (label > 0.5) outscores a random
    negative, ties counted half (the Mann-Whitney statistic); None where one class is missing."""
    positive, scores = np.asarray(labels) > 0.5, np.asarray(scores, dtype=float)
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if not n_pos or not n_neg:
        return None
    _, inverse, counts = np.unique(scores, return_inverse=True, return_counts=True)
    average_rank = np.cumsum(counts) - (counts - 1) / 2  # 1-based ranks, ties averaged
    ranks = average_rank[inverse.reshape(-1)]
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def calibration_error(labels: np.ndarray, probabilities: np.ndarray, bins: int = 10) -> float | None:
    """Expected calibration error: over ``bins`` equal-width bins of predicted probability, the mean
    gap between predicted and observed success, weighted by each bin's share (None: no data)."""
    labels, probabilities = np.asarray(labels, dtype=float), np.asarray(probabilities, dtype=float)
    if not len(labels):
        return None
    index = np.minimum((probabilities * bins).astype(int), bins - 1)
    return float(sum(abs(probabilities[index == b].mean() - labels[index == b].mean()) * (index == b).mean()
                     for b in range(bins) if (index == b).any()))


def reliability(labels: np.ndarray, probabilities: np.ndarray, bins: int = 10) -> list[dict]:
    """Predicted against observed success per bin of predicted probability: the reliability diagram's
    points (bin range, count, mean prediction, observed rate)."""
    labels, probabilities = np.asarray(labels, dtype=float), np.asarray(probabilities, dtype=float)
    index = np.minimum((probabilities * bins).astype(int), bins - 1)
    return [{"bin": [round(b / bins, 2), round((b + 1) / bins, 2)], "count": int((index == b).sum()),
             "predicted": round(float(probabilities[index == b].mean()), 4), "observed": round(float(labels[index == b].mean()), 4)}
            for b in range(bins) if (index == b).any()]


def fit_platt(logits: np.ndarray, labels: np.ndarray, iterations: int = 200) -> tuple[float, float]:
    """(temperature, bias) such that sigmoid(logit / temperature + bias) best predicts ``labels`` (log
    loss; Platt scaling): a model trained on reweighted classes, or overconfident, made calibrated.

    Platt's smoothed targets ((N+ + 1) / (N+ + 2) for a success, 1 / (N- + 2) for a failure) keep the
    optimum finite when the scores separate the classes (a few trials), and the result is held to the
    range a weights file may carry (temperature 0.05..20, bias -20..20)."""
    logits, labels = np.asarray(logits, dtype=float), np.asarray(labels, dtype=float)
    positives, negatives = float(np.sum(labels > 0.5)), float(np.sum(labels <= 0.5))
    targets = np.where(labels > 0.5, (positives + 1) / (positives + 2), 1 / (negatives + 2))
    scale, bias = 1.0, 0.0
    for _ in range(iterations):  # Newton's method on the two parameters (a convex problem)
        z = np.clip(logits * scale + bias, -30, 30)
        p = 1.0 / (1.0 + np.exp(-z))
        gradient = np.array([np.sum((p - targets) * logits), np.sum(p - targets)])
        w = p * (1 - p) + 1e-9
        hessian = np.array([[np.sum(w * logits * logits), np.sum(w * logits)], [np.sum(w * logits), np.sum(w)]]) + 1e-6 * np.eye(2)
        step = np.linalg.solve(hessian, gradient)
        step *= min(1.0, 5.0 / max(np.abs(step).max(), 1e-12))  # damped: no leap out of the basin
        scale, bias = scale - step[0], bias - step[1]
        if np.abs(step).max() < 1e-8:
            break
    scale = float(np.clip(scale, 0.05, 20.0))
    bias = float(np.clip(bias, -20.0, 20.0))
    return 1.0 / scale, float(bias)
