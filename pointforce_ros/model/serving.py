"""Contact-wrench serving core: the current model, hot-swapped without dropping requests.

The contact service node wraps one :class:`WrenchServer`. Swapping builds the new simulator
outside any lock and then replaces one reference, so a request in flight finishes on the model it
started with and the next request sees the new one (read-copy-update). Pure Python, no ROS.

Accepted effects stored in the model (``ContactModel.effects``) are applied as their forward
terms (:mod:`pointforce_ros.effects.forward`): a surface offset the file has not applied yet, a
series compliance (the answer is the one at the pose moved back along the approach by
``compliance * F_n``, solved for the total normal force), and a viscoelastic hold fraction.
"""

import dataclasses
import threading
from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from pointforce_ros.contact import ContactSimulator
from pointforce_ros.contact.simulator import normalise_approach, poses_as_arrays
from pointforce_ros.effects.forward import ForwardTerms, model_surface, solve_retreat
from pointforce_ros.errors import ModelNotReady
from pointforce_ros.model.files import ContactModel, latest_model_path, load_model
from pointforce_ros.types import ContactQuery, Pose


class WrenchServer:
    """Answers :class:`ContactQuery` objects from the latest loaded :class:`ContactModel`."""

    def __init__(self, spacing: float = 0.003, *, series_compliance: bool = True,
                 hold_time: float = 0.0):
        """Create an empty server.

        Args:
            spacing: rigid-mesh sampling distance, metres.
            series_compliance: apply a series compliance the model's effects hold.
            hold_time: seconds a pose is held after a fast approach, for a viscoelastic
                effect (0: the instantaneous force).

        """
        self._spacing = float(spacing)
        self._series = bool(series_compliance)
        self._hold_time = float(hold_time)
        ForwardTerms.of({}, hold_time=self._hold_time)  # validates hold_time
        self._current: Optional[Tuple[ContactModel, ContactSimulator, ForwardTerms]] = None
        self._swap_lock = threading.Lock()
        self.loaded_path: Optional[Path] = None

    @property
    def version(self) -> int:
        """Version of the model answering now, or -1 when none is loaded."""
        current = self._current
        return -1 if current is None else int(current[0].version)

    def swap(self, model: ContactModel) -> None:
        """Make ``model`` the one that answers (older versions are ignored).

        Raises:
            InvalidInput: the model's effects are malformed.

        """
        terms = ForwardTerms.of(model.effects, series_compliance=self._series,
                                hold_time=self._hold_time)
        simulator = ContactSimulator(model_surface(model), model.response, model.shape_constant,
                                     spacing=self._spacing, decay=model.shape_decay)
        with self._swap_lock:
            if self._current is None or model.version >= self._current[0].version:
                self._current = (model, simulator, terms)

    @property
    def forward_terms(self) -> Optional[ForwardTerms]:
        """Forward terms of the model answering now (None when none is loaded)."""
        current = self._current
        return None if current is None else current[2]

    def load(self, path) -> ContactModel:
        """Load a model file and swap it in; raises DataError for a bad file."""
        model = load_model(path)
        self.swap(model)
        self.loaded_path = Path(path)
        return model

    def load_latest(self, directory) -> bool:
        """Load the newest model in ``directory`` if it is newer than the current one."""
        path = latest_model_path(directory)
        if path is None or path == self.loaded_path:
            return False
        self.load(path)
        return True

    def _snapshot(self) -> Tuple[ContactModel, ContactSimulator, ForwardTerms]:
        current = self._current
        if current is None:
            raise ModelNotReady('no contact model loaded yet: run the learner or give model_dir')
        return current

    def simulator(self) -> ContactSimulator:
        """Return the contact simulator of the current model (identification, tools).

        Raises:
            ModelNotReady: no model loaded.

        """
        return self._snapshot()[1]

    def answer(self, query: ContactQuery):
        """Answer the first pose of ``query``: returns (ContactResult, model version).

        Raises:
            ModelNotReady: no model loaded.
            InvalidInput: a query the simulator cannot use.

        """
        model, simulator, terms = self._snapshot()
        pose = query.poses[0]
        if terms.compliance > 0:
            shift = self._retreat(simulator, terms, query, query.poses[:1])[0]
            pose = Pose(position=pose.position - shift * normalise_approach(query.approach),
                        orientation=pose.orientation, frame=pose.frame)
        result = simulator.query(query.mesh, pose, query.approach, query.torque_centre,
                                 return_displacements=query.return_displacements)
        if terms.force_scale != 1.0:
            k = terms.force_scale
            wrench = dataclasses.replace(result.wrench, force=result.wrench.force * k,
                                         torque=result.wrench.torque * k)
            result = dataclasses.replace(result, wrench=wrench,
                                         contact_forces=result.contact_forces * k)
        return result, int(model.version)

    def answer_batch(self, query: ContactQuery):
        """Answer every pose of ``query``: returns (BatchContactResult, model version)."""
        model, simulator, terms = self._snapshot()
        poses = list(query.poses)
        if terms.compliance > 0:
            shift = self._retreat(simulator, terms, query, poses)
            poses = _shifted(poses, simulator.surface.frame, shift,
                             normalise_approach(query.approach))
        batch = simulator.query_batch(query.mesh, poses, query.approach, query.torque_centre)
        if terms.force_scale != 1.0:
            batch = dataclasses.replace(batch, wrenches=batch.wrenches * terms.force_scale)
        return batch, int(model.version)

    @staticmethod
    def _retreat(simulator: ContactSimulator, terms: ForwardTerms, query: ContactQuery,
                 poses) -> np.ndarray:
        """Retreat (B,) metres of each pose along the approach under the series compliance."""
        a = normalise_approach(query.approach)
        base = _as_rows(poses, simulator.surface.frame)
        centre = np.asarray(query.torque_centre, dtype=np.float64)

        def push_back(index, shift):
            rows = base[index].copy()
            rows[:, :3] -= shift[:, None] * a
            out = simulator.query_batch(query.mesh, rows, a, centre)
            return -terms.force_scale * (out.wrenches[:, :3] @ a)

        shift, _ = solve_retreat(push_back, terms.compliance, len(base))
        return shift


def _as_rows(poses, frame: str) -> np.ndarray:
    """(B, 7) ``[x, y, z, qx, qy, qz, qw]`` of ``poses`` (frames checked)."""
    poses_as_arrays(poses, frame)
    if isinstance(poses, np.ndarray):
        return np.array(poses, dtype=np.float64)
    return np.array([np.concatenate([p.position, p.orientation]) for p in poses])


def _shifted(poses, frame: str, shift: np.ndarray, a: np.ndarray) -> np.ndarray:
    rows = _as_rows(poses, frame)
    rows[:, :3] -= shift[:, None] * a
    return rows
