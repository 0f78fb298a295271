"""The expert demo as DREM reads it: one episode of a ManiSkill trajectory file (``RecordEpisode``'s .h5 + .json).

Only its observations (the first and last ones, for the reward's normalisation) and its environment states (the goal
state, and the end-effector poses the progress measure compares with) are used, never its actions.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import h5py

from drem_maniskill.utils.cameras import camera_roles
from drem_maniskill.utils.state import first_leaf


@dataclass
class ExpertTrajectory:
    """The parts of a recorded expert episode that DREM uses (no actions)."""

    env_id: str
    env_kwargs: dict
    episode_seed: Optional[int]
    camera_map: dict  # modality -> camera uid of the recorded observations
    first_obs: dict  # {modality}_rgb (and ft) of step 0
    last_obs: dict  # of step T
    states: dict = field(default_factory=dict)  # env states, every leaf [T + 1, ...]

    @property
    def length(self) -> int:
        """Number of recorded states (steps + 1)."""
        return len(first_leaf(self.states))


def _read_group(group) -> dict:
    out = {}
    for key, value in group.items():
        out[key] = _read_group(value) if isinstance(value, h5py.Group) else value[()]
    return out


def _cameras_in(sensor_data) -> dict:
    """Modality -> camera uid among recorded cameras (``utils.cameras.camera_roles``, as for a live env)."""
    return camera_roles([u for u in sensor_data.keys() if "rgb" in sensor_data[u]])


def load_expert(h5_path: str, episode: int = 0) -> ExpertTrajectory:
    """Read one episode of a ManiSkill trajectory file (``.h5`` with its ``.json`` beside it)."""
    h5_path = Path(h5_path)
    json_path = h5_path.with_suffix(".json")
    if not h5_path.exists():
        raise FileNotFoundError(f"expert trajectory {h5_path} not found; record one with "
                                "`drem-maniskill record-expert`")
    if not json_path.exists():
        raise FileNotFoundError(f"{json_path} (the metadata RecordEpisode writes beside {h5_path.name}) not found")
    try:
        meta = json.loads(json_path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{json_path} is not valid JSON ({err}); re-record the expert") from err
    episodes = meta.get("episodes", [])
    if episode >= len(episodes):
        raise ValueError(f"{h5_path} has {len(episodes)} episodes; episode {episode} does not exist")
    ep = episodes[episode]
    try:
        with h5py.File(h5_path, "r") as f:
            traj = f[f"traj_{ep.get('episode_id', episode)}"]
            if "env_states" not in traj:
                raise ValueError(f"{h5_path} has no env_states; record with RecordEpisode(record_env_state=True)")
            # A state-mode recording stores its observations as one flat dataset, with no camera group in it.
            obs = traj["obs"] if isinstance(traj.get("obs"), h5py.Group) else {}
            cams = _cameras_in(obs["sensor_data"]) if "sensor_data" in obs else {}
            if not cams:
                raise ValueError(
                    f"{h5_path} has no camera images in its observations: record the expert with obs_mode='rgb' "
                    "(drem-maniskill record-expert does)"
                )
            states = _read_group(traj["env_states"])
            images = {m: obs[f"sensor_data/{uid}/rgb"] for m, uid in cams.items()}
            ft = obs["extra/ft"][()] if "extra" in obs and "ft" in obs["extra"] else None

            def pick(i):
                """The camera images (and F/T) of step ``i``."""
                out = {f"{m}_rgb": images[m][i] for m in images}
                if ft is not None:
                    out["ft"] = ft[i]
                return out

            first, last = pick(0), pick(-1)
    except OSError as err:
        raise ValueError(f"cannot read {h5_path}: {err}. Is it a complete HDF5 file? Re-record it.") from err
    kwargs = dict(meta["env_info"].get("env_kwargs", {}))
    return ExpertTrajectory(
        env_id=meta["env_info"]["env_id"], env_kwargs=kwargs, episode_seed=ep.get("episode_seed"),
        camera_map=cams, first_obs=first, last_obs=last, states=states,
    )
