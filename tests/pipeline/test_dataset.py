"""The progress tree as training data: what it refuses."""

from __future__ import annotations

import json

import h5py
import pytest

from drem_maniskill.pipeline.train_reward import TrainConfig, train_reward


@pytest.mark.slow
def test_dataset_without_start_region_is_rejected(pipeline, tmp_path):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(open(pipeline["tree"], "rb").read())
    with h5py.File(bad, "a") as f:
        f["in_start_region"][...] = False
    with pytest.raises(ValueError, match="no start-region states"):
        train_reward(str(bad), str(tmp_path / "r"), TrainConfig.preset("tiny"), progress=False)


def test_tree_report_places_nodes_around_the_opening(tmp_path):
    """Regions from the tip position and the wrist force, with the depths of their nodes."""
    import h5py
    import numpy as np

    from drem_maniskill.pipeline.dataset import tree_report

    tip = np.array([[0, 0, -0.02], [0, 0, -0.005], [0.001, 0, 0.004], [0.005, 0, 0.003], [0.004, 0, 0.0],
                    [0.05, 0, 0.05],
                    [0.06, 0.02, -0.045]])
    force = np.array([0.0, 2.0, 0.0, 0.0, 8.0, 0.0, 20.0])
    ft = np.zeros((len(tip), 8, 6), np.float32)
    ft[:, -1, 2] = -force
    with h5py.File(tmp_path / "tree.h5", "w") as f:
        f["tip_in_socket"], f["depth"], f["ft"] = tip, np.array([0, 1, 3, 4, 4, 9, 12]), ft
        f.attrs["header"] = json.dumps(dict(env_id="PegInHole-v1"))  # the opening's geometry: the task's
    report = tree_report(str(tmp_path / "tree.h5"))
    assert report["inserted"] == dict(nodes=2, depth_mean=0.5, depth_min=0, depth_max=1)
    assert report["above, centred"]["nodes"] == 1 and report["above, centred"]["depth_min"] == 3
    assert report["above, off-centre"]["nodes"] == 1 and report["in contact, not inserted"]["depth_max"] == 4
    # Pressed on the floor beside the socket: neither inserted nor contact at the opening.
    assert report["beside, below the top face"] == dict(nodes=1, depth_mean=12.0, depth_min=12, depth_max=12)
    assert report["far"]["nodes"] == 1 and report["tree_depth"] == 12
    with h5py.File(tmp_path / "stock.h5", "w") as f:
        f["depth"] = np.zeros(1)
    assert tree_report(str(tmp_path / "stock.h5")) == {}


def test_a_tree_records_its_socket_geometry_and_older_ones_read_their_tasks(tmp_path):
    """The opening's geometry comes from the task (the tree's header, else its env's class); a stock task has none."""
    import numpy as np

    from drem_maniskill.envs.adapter import SocketGeometry, socket_geometry_of
    from drem_maniskill.pipeline.tree.tree_file import tree_geometry

    usb = socket_geometry_of("USBInsertion-v1")
    assert usb.opening_radius == 0.01 and usb.inserted_height == -0.001 and usb.socket_height > 0.02
    assert socket_geometry_of("PegInsertionSide-v1") is None and socket_geometry_of("NoSuchEnv-v0") is None
    assert list(usb.in_opening(np.array([[0, 0, -0.005], [0.02, 0, -0.005], [0, 0, 0.001]]))) == [True, False, False]
    recorded = SocketGeometry(0.02, -0.002, 0.0, 0.03)
    with h5py.File(tmp_path / "new.h5", "w") as f:
        f.attrs["header"] = json.dumps(dict(env_id="USBInsertion-v1", socket_geometry=recorded.__dict__))
        assert tree_geometry(f) == recorded
    with h5py.File(tmp_path / "stock.h5", "w") as f:
        f.attrs["header"] = json.dumps(dict(env_id="PegInsertionSide-v1"))
        with pytest.raises(ValueError, match="no opening"):
            tree_geometry(f)


def test_an_unfinished_or_foreign_file_names_the_command_that_makes_a_tree(tmp_path):
    from drem_maniskill.pipeline.dataset import dataset_modalities
    from drem_maniskill.pipeline.tree.tree_file import open_tree

    with pytest.raises(FileNotFoundError, match="drem-maniskill sample"):
        open_tree(tmp_path / "none.h5")
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="drem-maniskill sample"):
        open_tree(tmp_path / "junk.h5")
    with h5py.File(tmp_path / "partial.h5", "w") as f:
        f.attrs["header"] = "{}"
    with pytest.raises(ValueError, match="unfinished.*drem-maniskill sample"):
        open_tree(tmp_path / "partial.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f.attrs["complete"] = True
    with pytest.raises(ValueError, match="not a progress tree.*drem-maniskill sample"):
        open_tree(tmp_path / "other.h5")
    # The default modalities: TreeDataset says what is wrong with the file.
    assert dataset_modalities(str(tmp_path / "partial.h5")) == ("fixed", "wrist", "ft")


@pytest.mark.slow
def test_the_dataset_hands_on_the_trees_config_and_refuses_one_it_cannot_read(pipeline, tmp_path):
    """A tree's sampler config reaches the dataset with every field; one this version cannot read names the fix."""
    from drem_maniskill.drem.model import ModelConfig
    from drem_maniskill.pipeline.dataset import TreeDataset
    from drem_maniskill.pipeline.tree.config import SamplerConfig

    config = ModelConfig(image_size=64)
    assert TreeDataset(pipeline["tree"], config).header["config"] == SamplerConfig.preset("tiny").to_dict()
    old = tmp_path / "old.h5"
    old.write_bytes(open(pipeline["tree"], "rb").read())
    with h5py.File(old, "a") as f:
        header = json.loads(f.attrs["header"])
        del header["socket_geometry"]
    for unread in (dict(num_children=4, max_depth=40, outward_depth=0), dict(wiggle_depth=3)):
        with h5py.File(old, "a") as f:
            f.attrs["header"] = json.dumps({**header, "config": unread})
        with pytest.raises(ValueError, match=f"{list(unread)[-1]}.*drem-maniskill sample"):
            TreeDataset(str(old), config)


def test_travel_labels_put_a_child_that_wandered_farther_than_one_beside_its_seed(tmp_path):
    """Seeds keep their depth; another child gets its seed's depth plus its hand's move from the seed over the demo's
    median step (rotation weighted as the sampler weighs it), so two children of one depth differ."""
    import numpy as np

    from drem_maniskill.pipeline.dataset import travel_labels

    q = [1.0, 0, 0, 0]
    turned = [np.cos(0.05), np.sin(0.05), 0, 0]  # 0.1 rad about x
    tcp = np.array([[0, 0, 0.00, *q],      # goal, seed of depth 0
                    [0, 0, 0.01, *q],      # depth 1, seed: 10 mm above the goal
                    [0.002, 0, 0.0, *q],   # depth 1, 2 mm beside the goal
                    [0, 0, 0.0, *turned],  # depth 1, turned 0.1 rad at the goal
                    [0.006, 0, 0.01, *q],  # depth 2, 6 mm beside its seed (node 1)
                    [0, 0, 0.011, *q]])    # depth 2, 1 mm above its seed
    demo = np.array([[0, 0, z, *q] for z in (0.006, 0.004, 0.002, 0.0)])  # the demo's median step: 2 mm
    with h5py.File(tmp_path / "tree.h5", "w") as f:
        f["depth"], f["parent"] = np.array([0, 1, 1, 1, 2, 2]), np.array([-1, 0, 0, 0, 1, 1])
        f["is_seed"] = np.array([True, True, False, False, False, False])
        f["tcp_pose"], f["expert/tcp_pose"] = tcp, demo
        f.attrs["header"] = json.dumps(dict(env_id="PegInHole-v1", config=dict(rotation_weight=0.05)))
    with h5py.File(tmp_path / "tree.h5", "r") as f:
        labels = travel_labels(f)
        doubled = travel_labels(f, scale=2.0)
    # 0.1 rad at 0.05 m/rad is 5 mm of travel: 2.5 steps.
    assert np.allclose(labels, [0, 1, 1.0, 2.5, 4.0, 1.5])
    assert np.allclose(doubled, [0, 1, 2.0, 5.0, 7.0, 2.0])
    with h5py.File(tmp_path / "still.h5", "w") as f:
        f["depth"], f["parent"], f["is_seed"] = np.array([0, 1]), np.array([-1, 0]), np.array([True, False])
        f["tcp_pose"], f["expert/tcp_pose"] = tcp[:2], np.array([tcp[0], tcp[0]])
        f.attrs["header"] = json.dumps(dict(env_id="PegInHole-v1"))
    with h5py.File(tmp_path / "still.h5", "r") as f, pytest.raises(ValueError, match="never moves"):
        travel_labels(f)
    with h5py.File(tmp_path / "older.h5", "w") as f:  # a tree without its parent links
        f["depth"], f["tcp_pose"], f["expert/tcp_pose"] = np.array([0, 1]), tcp[:2], demo
    with h5py.File(tmp_path / "older.h5", "r") as f, pytest.raises(ValueError, match="parent.*re-sample"):
        travel_labels(f)


@pytest.mark.slow
def test_training_with_travel_labels_reads_them_and_resumes_only_under_them(pipeline, tmp_path):
    """The dataset hands the loss travel labels when asked (depths otherwise); a training state resumes under the
    labelling it was saved with, one saved before the setting existed as depths, never under the other."""
    from dataclasses import asdict

    import torch

    from drem_maniskill.pipeline import train_reward as tr
    from drem_maniskill.pipeline.dataset import TreeDataset

    config = TrainConfig.preset("tiny")
    plain = TreeDataset(pipeline["tree"], config.model)
    travel = TreeDataset(pipeline["tree"], config.model, travel=1.0)
    assert torch.equal(plain.label, plain.depth.float())
    with h5py.File(pipeline["tree"], "r") as f:
        seeds = torch.as_tensor(f["is_seed"][()])
    assert torch.equal(travel.label[seeds], travel.depth[seeds].float())
    assert not torch.equal(travel.label[~seeds], travel.depth[~seeds].float())
    train_reward(pipeline["tree"], str(tmp_path / "r"), config, progress=False)
    state_path = tmp_path / "r" / "train_state.pt"

    def resumes_at(cfg: TrainConfig) -> int:
        model = tr._build_model(cfg, plain, None)
        opt, gen = torch.optim.Adam(model.parameters()), torch.Generator()
        return tr._resume(state_path, model, opt, gen, json.loads(json.dumps(asdict(cfg))), pipeline["tree"],
                          len(plain.depth))

    travelled = TrainConfig.preset("tiny", travel_labels=1.0)
    assert resumes_at(config) == config.iterations and resumes_at(travelled) == 0
    state = torch.load(state_path, weights_only=True)
    older = {k: v for k, v in json.loads(state["config"]).items() if k != "travel_labels"}
    torch.save({**state, "config": json.dumps(older)}, state_path)
    assert resumes_at(config) == config.iterations and resumes_at(travelled) == 0


def test_resize_images_reads_a_tree_camera_in_chunks_with_the_same_result(tmp_path):
    """A camera read and resized a chunk at a time, from an array or straight from the tree file, matches the whole
    array area-averaged at once; a camera already at the size comes back unchanged."""
    import h5py
    import numpy as np
    import torch
    import torch.nn.functional as F

    from drem_maniskill.pipeline.dataset import resize_images

    images = np.random.default_rng(0).integers(0, 256, size=(10, 16, 16, 3), dtype=np.uint8)
    whole = F.interpolate(torch.as_tensor(images).permute(0, 3, 1, 2).float(), size=(8, 8), mode="area")
    expected = whole.round().clamp(0, 255).to(torch.uint8).permute(0, 2, 3, 1)
    with h5py.File(tmp_path / "tree.h5", "w") as f:
        f.create_dataset("fixed_rgb", data=images, chunks=(1, 16, 16, 3), compression="gzip")
    with h5py.File(tmp_path / "tree.h5", "r") as f:
        chunked = resize_images(f["fixed_rgb"], 8, chunk=3)
        assert torch.equal(resize_images(f["fixed_rgb"], 16), torch.as_tensor(images))
    assert chunked.dtype == torch.uint8 and chunked.shape == (10, 8, 8, 3)
    assert torch.equal(chunked, expected)
    assert torch.equal(resize_images(images, 8, chunk=4), expected)
    assert not torch.equal(expected[:3], expected[3:6])  # distinct images: a chunk written to the wrong rows shows
