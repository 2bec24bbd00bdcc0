"""Gaussian-process dynamics model of thesis §3.3.1 (Eq 3.8-3.16): x = (z, a) -> Δz.

One exact GP per output dimension (a GPyTorch batch), each with an ARD RBF kernel, zero mean and
Gaussian noise ε (Eq 3.14); hyper-parameters maximise the marginal likelihood (Eq 3.9). Inputs and
outputs are standardised so one set of optimiser settings works for any robot's units.

Prediction uses the closed form of Eq 3.12-3.13 with α = K⁻¹y and the leading eigen-directions of
K cached once after fitting (see ``_cache_posterior``), so a batch of B imagined steps costs two
small products per output. tests/test_dynamics.py checks mean and variance against a float64 solve;
GPyTorch's own float32 predictive path was several times slower at B = 1000 and less accurate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import gpytorch
import numpy as np
import torch

from binpick.core import tensorfile
from binpick.core.config import check_range
from binpick.rl.config.gp_her import GPConfig
from binpick.core.errors import InputFileError
from binpick.core.files import require_fields


class _IndependentGPs(gpytorch.models.ExactGP):
    def __init__(self, x: torch.Tensor, y: torch.Tensor, likelihood) -> None:
        super().__init__(x, y, likelihood)
        outputs = torch.Size([y.shape[-1]])
        self.mean_module = gpytorch.means.ZeroMean(batch_shape=outputs)
        self.covar_module = gpytorch.kernels.ScaleKernel(
            gpytorch.kernels.RBFKernel(ard_num_dims=x.shape[-1], batch_shape=outputs), batch_shape=outputs
        )

    def forward(self, x):
        return gpytorch.distributions.MultitaskMultivariateNormal.from_batch_mvn(
            gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))
        )


@dataclass
class FitReport:
    points: int
    iterations: int
    seconds: float
    negative_mll: float


class GPDynamics:
    """Learns Δz = D(z, a) from transitions and predicts or samples next states in batches."""

    def __init__(self, max_points: int = 1000, iterations: int = 60, learning_rate: float = 0.1, seed: int = 0) -> None:
        settings = GPConfig(max_points=max_points, iterations=iterations)  # the config's rules, written once
        self.max_points, self.iterations = settings.max_points, settings.iterations
        self.learning_rate = check_range("gp.learning_rate", learning_rate, 0.0, 10.0, low_inclusive=False)
        self.seed = seed
        self.model: _IndependentGPs | None = None
        self.likelihood = None
        self._x_mean = self._x_std = self._y_mean = self._y_std = None

    @property
    def fitted(self) -> bool:
        return self.model is not None

    def fit(self, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray) -> FitReport:
        """Fit on transitions (z_t, a_t, z_{t+1}); keeps at most ``max_points`` of them, at random."""
        x = np.concatenate([states, actions], axis=1).astype(np.float64)
        y = (next_states - states).astype(np.float64)
        if len(x) < 2:
            raise ValueError("the GP needs at least 2 transitions to fit")
        rng = np.random.default_rng(self.seed)
        if len(x) > self.max_points:
            keep = rng.choice(len(x), self.max_points, replace=False)
            x, y = x[keep], y[keep]
        self._x_mean, self._x_std = x.mean(0), x.std(0) + 1e-6
        self._y_mean, self._y_std = y.mean(0), y.std(0) + 1e-6
        train_x = torch.as_tensor((x - self._x_mean) / self._x_std, dtype=torch.float32)
        train_y = torch.as_tensor((y - self._y_mean) / self._y_std, dtype=torch.float32)
        torch.manual_seed(self.seed)
        self.likelihood = gpytorch.likelihoods.MultitaskGaussianLikelihood(num_tasks=y.shape[1])
        self.model = _IndependentGPs(train_x, train_y, self.likelihood)
        self.model.train()
        self.likelihood.train()
        optimiser = torch.optim.Adam(self.model.parameters(), lr=self.learning_rate)
        mll = gpytorch.mlls.ExactMarginalLogLikelihood(self.likelihood, self.model)
        started = time.perf_counter()
        for _ in range(self.iterations):
            optimiser.zero_grad()
            loss = -mll(self.model(train_x), train_y)
            loss.backward()
            optimiser.step()
        self.model.eval()
        self.likelihood.eval()
        self._cache_posterior()
        return FitReport(len(x), self.iterations, time.perf_counter() - started, float(loss.detach()))

    def _cache_posterior(self) -> None:
        """K⁻¹ and α = K⁻¹y per output (float64 Cholesky, float32 for prediction)."""
        with torch.no_grad():
            kernel = self.model.covar_module
            lengthscale = kernel.base_kernel.lengthscale.double()  # (t, 1, d)
            outputscale = kernel.outputscale.double()  # (t,)
            noise = (self.likelihood.noise + self.likelihood.task_noises).double()  # (t,)
            train_x = self.model.train_inputs[0].double() / lengthscale  # (t, n, d)
            train_y = self.model.train_targets.double().T  # (t, n)
            signal = outputscale[:, None, None] * torch.exp(-0.5 * torch.cdist(train_x, train_x).square())
            gram = signal + noise[:, None, None] * torch.eye(train_x.shape[1], dtype=torch.float64)
            cholesky = torch.linalg.cholesky(gram)
            # k*ᵀK⁻¹k* through K_f = U Λ Uᵀ: K⁻¹ = U (Λ + σ²)⁻¹ Uᵀ. A kernel row's weight on eigenvector j
            # is ~λ_j, so component j adds at most λ_j²/σ² to k*ᵀK⁻¹k*. Dropping all λ_j < σ·sqrt(1e-4·s²)
            # (s² = outputscale) changes a variance by < 1e-4·s², far below the noise σ²; the remaining
            # r << n columns make the variance an (B × n) @ (n × r) product instead of (n × n).
            eigenvalues, eigenvectors = torch.linalg.eigh(signal)
            cutoff = torch.sqrt(noise * 1e-4 * outputscale)
            keep = eigenvalues >= cutoff[:, None]
            rank = max(int(keep.sum(-1).max()), 1)
            top_values, top_vectors = eigenvalues[:, -rank:], eigenvectors[:, :, -rank:]
            projection = top_vectors / torch.sqrt(top_values.clamp_min(0) + noise[:, None])[:, None, :]
            self._post = {
                "scaled_x": train_x.float(), "lengthscale": lengthscale.float(), "outputscale": outputscale.float(),
                "noise": noise.float(), "projection": projection.float(), "rank": rank,
                "alpha": torch.cholesky_solve(train_y[..., None], cholesky)[..., 0].float(),
            }

    def predict(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Predictive mean and variance of Δz (with the noise ε) for a batch of (z, a)."""
        if self.model is None:
            raise RuntimeError("fit() the GP before predicting")
        post = self._post
        x = torch.as_tensor((np.concatenate([states, actions], axis=1) - self._x_mean) / self._x_std, dtype=torch.float32)
        with torch.no_grad():
            query = x[None] / post["lengthscale"]  # (t, B, d)
            cross = post["outputscale"][:, None, None] * torch.exp(-0.5 * torch.cdist(query, post["scaled_x"]).square())
            mean = torch.einsum("tbn,tn->tb", cross, post["alpha"])
            explained = (cross @ post["projection"]).square().sum(-1)
            variance = (post["outputscale"][:, None] - explained).clamp_min(1e-10) + post["noise"][:, None]
        return mean.T.numpy() * self._y_std + self._y_mean, variance.T.numpy() * self._y_std**2

    def sample_next(self, states: np.ndarray, actions: np.ndarray, rng: np.random.Generator,
                    stochastic: bool = True) -> np.ndarray:
        """z_{t+1} = z_t + Δz with Δz drawn from the predictive distribution (Eq 3.16)."""
        mean, variance = self.predict(states, actions)
        delta = mean + np.sqrt(variance) * rng.standard_normal(mean.shape) if stochastic else mean
        return states + delta

    FORMAT = "binpick-gp-dynamics-1"

    def save(self, path: str | Path) -> None:
        """The fitted GP as safetensors (hyper-parameters, training points, standardisation) + JSON settings."""
        if self.model is None:
            raise RuntimeError("nothing to save: the GP is not fitted")
        state = {"model": self.model.state_dict(), "likelihood": self.likelihood.state_dict(),
                 "train_x": self.model.train_inputs[0], "train_y": self.model.train_targets,
                 "norm": [np.asarray(v) for v in (self._x_mean, self._x_std, self._y_mean, self._y_std)]}
        settings = {"max_points": self.max_points, "iterations": self.iterations, "learning_rate": self.learning_rate,
                    "seed": self.seed}
        tensorfile.save(path, self.FORMAT, state=state, meta={"settings": settings})

    @classmethod
    def load(cls, path: str | Path) -> GPDynamics:
        _, meta, state = tensorfile.load(path, cls.FORMAT, "GP dynamics model")
        where = f"GP dynamics model {str(path)!r}"
        require_fields(meta, {"settings": dict}, where)
        require_fields(state or {}, {"model": dict, "likelihood": dict, "train_x": torch.Tensor, "train_y": torch.Tensor,
                                     "norm": list}, where)
        try:
            gp = cls(**meta["settings"])
            gp._x_mean, gp._x_std, gp._y_mean, gp._y_std = state["norm"]
            gp.likelihood = gpytorch.likelihoods.MultitaskGaussianLikelihood(num_tasks=state["train_y"].shape[-1])
            gp.model = _IndependentGPs(state["train_x"], state["train_y"], gp.likelihood)
            gp.model.load_state_dict(state["model"])
            gp.likelihood.load_state_dict(state["likelihood"])
        except (TypeError, ValueError, RuntimeError, IndexError) as error:
            raise InputFileError(f"{where} is damaged ({str(error).splitlines()[0][:120]})") from None
        gp.model.eval()
        gp.likelihood.eval()
        gp._cache_posterior()
        return gp
