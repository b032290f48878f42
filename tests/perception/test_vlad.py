"""VLAD descriptors: the vocabulary, the aggregation and its normalisations, PCA."""

import numpy as np
import pytest

from kartpilot.core.errors import ConfigError, PerceptionError
from kartpilot.perception.vlad import VladConfig, fit_pca, project_pca, train_vocabulary, vlad_vector


def _blobs(rng: np.random.Generator, centres: np.ndarray, per: int) -> np.ndarray:
    return np.concatenate([c + rng.normal(0, 1.0, (per, centres.shape[1])) for c in centres]).astype(np.float32)


def test_the_vocabulary_finds_the_words_the_descriptors_cluster_around():
    rng = np.random.default_rng(0)
    centres = rng.uniform(0, 100, (4, 16))
    sets = [_blobs(rng, centres, 50) for _ in range(5)]
    words = train_vocabulary(sets, VladConfig(words=4))
    nearest = np.min(np.linalg.norm(words[:, None] - centres[None], axis=2), axis=0)
    assert words.shape == (4, 16)
    assert nearest.max() < 0.5  # every true centre has a word within half a standard deviation


def test_too_few_descriptors_for_the_vocabulary_is_an_error_that_says_so():
    with pytest.raises(PerceptionError, match="vocabulary of 64 words"):
        train_vocabulary([np.zeros((10, 128), np.float32)], VladConfig())


def test_vlad_is_unit_length_and_zero_without_descriptors():
    rng = np.random.default_rng(1)
    words = rng.uniform(0, 10, (8, 4)).astype(np.float32)
    vector = vlad_vector(rng.uniform(0, 10, (40, 4)), words)
    assert vector.shape == (32,)
    assert np.linalg.norm(vector) == pytest.approx(1.0, abs=1e-5)
    assert not vlad_vector(np.zeros((0, 4), np.float32), words).any()
    with pytest.raises(PerceptionError, match="dimension 4"):
        vlad_vector(np.zeros((3, 5), np.float32), words)


def test_intra_normalisation_keeps_a_bursty_word_from_drowning_the_others():
    """A hundred descriptors of one repeated pattern next to a single other one: without intra-normalisation
    the repeated word holds nearly the whole vector; with it, both words weigh the same."""
    words = np.array([[0.0, 0.0], [10.0, 10.0]], np.float32)
    burst = np.tile([[1.0, 0.0]], (100, 1))
    single = np.array([[11.0, 10.0]])
    vector = vlad_vector(np.r_[burst, single], words, power_alpha=1.0).reshape(2, 2)
    block_norms = np.linalg.norm(vector, axis=1)
    assert block_norms[0] == pytest.approx(block_norms[1])


def test_power_normalisation_evens_out_the_components():
    words = np.zeros((1, 3), np.float32)
    descriptors = np.array([[9.0, 1.0, 0.0]])
    plain = vlad_vector(descriptors, words, power_alpha=1.0)
    rooted = vlad_vector(descriptors, words, power_alpha=0.5)
    assert plain[0] / plain[1] == pytest.approx(9.0)
    assert rooted[0] / rooted[1] == pytest.approx(3.0)


def test_pca_gives_unit_vectors_of_the_asked_size_and_needs_more_vectors_than_dimensions():
    rng = np.random.default_rng(2)
    vectors = rng.normal(size=(30, 64)).astype(np.float32)
    pca = fit_pca(vectors, 8)
    projected = project_pca(vectors, pca)
    assert projected.shape == (30, 8)
    assert np.allclose(np.linalg.norm(projected, axis=1), 1.0, atol=1e-5)
    assert project_pca(vectors[0], pca).shape == (8,)
    with pytest.raises(ConfigError, match="more than 30"):
        fit_pca(vectors, 30)


def test_config_rejects_nonsense():
    with pytest.raises(ConfigError, match="words"):
        VladConfig(words=1)
    with pytest.raises(ConfigError, match="power_alpha"):
        VladConfig(power_alpha=0.0)
