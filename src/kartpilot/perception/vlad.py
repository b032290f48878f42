"""VLAD image descriptors for place recognition (the thesis's design, finished).

An image becomes one fixed-length vector:

1. Local features (SIFT by default, ORB as an option) from the same detectors as VO
   (:mod:`kartpilot.perception.features`).
2. A visual vocabulary: k-means (64 words by default) over descriptors of the reference images.
3. VLAD (Jegou et al., "Aggregating local descriptors into a compact image representation",
   CVPR 2010): each descriptor's residual to its nearest word, summed per word.
4. Normalisation as in Arandjelovic and Zisserman, "All about VLAD" (CVPR 2013): each word's
   block is L2-normalised (intra-normalisation, so a few bursty words, a repeated cone or kerb
   pattern, cannot dominate), then signed power normalisation ``sign(x) |x|^alpha``, then L2
   over the whole vector. Two images are then compared by Euclidean distance
   (``|a - b|^2 = 2 - 2 a.b``).
5. Optionally PCA (fitted on the database) to a compact size, whitened, and L2-normalised again.

Everything here is a pure function of arrays; the database that keeps the vectors and their
positions is :mod:`kartpilot.odometry.places`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kartpilot.core.errors import ConfigError, PerceptionError
from kartpilot.perception.features import FeatureConfig

__all__ = ["Pca", "VladConfig", "fit_pca", "project_pca", "train_vocabulary", "vlad_vector"]

F32 = NDArray[np.float32]


def _default_features() -> FeatureConfig:
    return FeatureConfig(detector="sift", max_features=1000, grid_rows=3, grid_cols=4)


@dataclass(frozen=True)
class VladConfig:
    """Attributes:
        features: the local features (SIFT by default; ``orb`` works, its bits taken as numbers).
        words: the vocabulary's size (k-means centres).
        power_alpha: the exponent of the signed power normalisation (0.5: signed square root; 1: none).
        pca_dims: project onto this many principal components (0: keep the full ``words x 128`` vector).
        train_descriptors: at most this many descriptors, drawn evenly from the images, train the vocabulary.
        kmeans_restarts: k-means runs from different starts; the one with the lowest inertia is kept.
        seed: k-means' random state, so a database is built the same way twice.
    """

    features: FeatureConfig = field(default_factory=_default_features)
    words: int = 64
    power_alpha: float = 0.5
    pca_dims: int = 0
    train_descriptors: int = 60_000
    kmeans_restarts: int = 2
    seed: int = 0

    def __post_init__(self) -> None:
        if self.words < 2:
            raise ConfigError(f"places.vlad.words must be at least 2, got {self.words}")
        if not 0 < self.power_alpha <= 1:
            raise ConfigError(f"places.vlad.power_alpha must be in (0, 1], got {self.power_alpha}")
        if self.pca_dims < 0:
            raise ConfigError(f"places.vlad.pca_dims must not be negative, got {self.pca_dims}")


def train_vocabulary(descriptor_sets: Sequence[NDArray[np.generic]], config: VladConfig) -> F32:
    """The ``(words, D)`` k-means centres of descriptors drawn evenly from every image."""
    sets = [np.asarray(d, np.float32) for d in descriptor_sets if len(d)]
    total = sum(len(d) for d in sets)
    if total < config.words:
        raise PerceptionError(f"{total} descriptors cannot train a vocabulary of {config.words} words: "
                              "the reference images have (almost) no texture")
    rng = np.random.default_rng(config.seed)
    share = min(1.0, config.train_descriptors / total)
    sample = np.concatenate([d[rng.random(len(d)) < share] if share < 1.0 else d for d in sets])
    if len(sample) < config.words:
        sample = np.concatenate(sets)
    from sklearn.cluster import KMeans  # here, not at import: scikit-learn takes most of a second to load

    kmeans = KMeans(config.words, n_init=config.kmeans_restarts, random_state=config.seed, max_iter=100)
    kmeans.fit(sample)
    return np.ascontiguousarray(kmeans.cluster_centers_, np.float32)


def vlad_vector(descriptors: NDArray[np.generic], centres: F32, power_alpha: float = 0.5) -> F32:
    """The normalised VLAD vector (length ``words * D``) of one image's descriptors.

    An image without descriptors gives the zero vector (it matches nothing better than anything else);
    the caller decides whether such an image may be used.
    """
    words, dim = centres.shape
    d = np.asarray(descriptors, np.float32)
    if d.ndim != 2 or (len(d) and d.shape[1] != dim):
        raise PerceptionError(f"descriptors of shape {d.shape} do not fit a vocabulary of dimension {dim}")
    out = np.zeros((words, dim), np.float32)
    if len(d) == 0:
        return out.ravel()
    squared = (d * d).sum(1)[:, None] - 2.0 * d @ centres.T + (centres * centres).sum(1)[None, :]
    nearest = np.argmin(squared, axis=1)
    np.add.at(out, nearest, d - centres[nearest])
    norms = np.linalg.norm(out, axis=1, keepdims=True)
    out = np.divide(out, norms, out=np.zeros_like(out), where=norms > 0)  # intra-normalisation
    out = np.sign(out) * np.abs(out) ** power_alpha
    flat = out.ravel()
    norm = float(np.linalg.norm(flat))
    return flat / norm if norm > 0 else flat


@dataclass(frozen=True)
class Pca:
    """A whitening projection: ``(x - mean) @ components.T / sqrt(variances)``."""

    mean: F32
    components: F32
    variances: F32


def fit_pca(vectors: F32, dims: int, seed: int = 0) -> Pca:
    """Principal components of the database's VLAD vectors (at most one fewer than there are vectors)."""
    from sklearn.decomposition import PCA

    count = len(vectors)
    if dims >= count:
        raise ConfigError(f"places.vlad.pca_dims {dims} needs more than {dims} database images, "
                          f"there are {count}")
    pca = PCA(dims, random_state=seed).fit(vectors)
    return Pca(pca.mean_.astype(np.float32), pca.components_.astype(np.float32),
               np.maximum(pca.explained_variance_, 1e-12).astype(np.float32))


def project_pca(vectors: F32, pca: Pca) -> F32:
    """Whitened, L2-normalised projections of ``(N, D)`` vectors (or one ``(D,)`` vector)."""
    x = np.atleast_2d(np.asarray(vectors, np.float32))
    projected = (x - pca.mean) @ pca.components.T / np.sqrt(pca.variances)
    norms = np.linalg.norm(projected, axis=1, keepdims=True)
    projected = np.divide(projected, norms, out=np.zeros_like(projected), where=norms > 0)
    return projected if np.ndim(vectors) == 2 else projected[0]
