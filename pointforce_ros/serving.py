"""Contact-wrench serving core: the current model, hot-swapped without dropping requests.

The contact service node wraps one :class:`WrenchServer`. Swapping builds the new simulator
outside any lock and then replaces one reference, so a request in flight finishes on the model it
started with and the next request sees the new one (read-copy-update). Pure Python, no ROS.
"""

import threading
from pathlib import Path
from typing import Optional, Tuple

from pointforce_ros.contact import ContactSimulator
from pointforce_ros.errors import ModelNotReady
from pointforce_ros.model_io import ContactModel, latest_model_path, load_model
from pointforce_ros.types import ContactQuery


class WrenchServer:
    """Answers :class:`ContactQuery` objects from the latest loaded :class:`ContactModel`."""

    def __init__(self, spacing: float = 0.003):
        """Create an empty server; ``spacing`` (m) is the rigid-mesh sampling distance."""
        self._spacing = float(spacing)
        self._current: Optional[Tuple[ContactModel, ContactSimulator]] = None
        self._swap_lock = threading.Lock()
        self.loaded_path: Optional[Path] = None

    @property
    def version(self) -> int:
        """Version of the model answering now, or -1 when none is loaded."""
        current = self._current
        return -1 if current is None else int(current[0].version)

    def swap(self, model: ContactModel) -> None:
        """Make ``model`` the one that answers (older versions are ignored)."""
        simulator = ContactSimulator(model.surface, model.response, model.shape_constant,
                                     spacing=self._spacing)
        with self._swap_lock:
            if self._current is None or model.version >= self._current[0].version:
                self._current = (model, simulator)

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

    def _snapshot(self) -> Tuple[ContactModel, ContactSimulator]:
        current = self._current
        if current is None:
            raise ModelNotReady('no contact model loaded yet: run the learner or give model_dir')
        return current

    def answer(self, query: ContactQuery):
        """Answer the first pose of ``query``: returns (ContactResult, model version).

        Raises:
            ModelNotReady: no model loaded.
            InvalidInput: a query the simulator cannot use.

        """
        model, simulator = self._snapshot()
        result = simulator.query(query.mesh, query.poses[0], query.approach, query.torque_centre,
                                 return_displacements=query.return_displacements)
        return result, int(model.version)

    def answer_batch(self, query: ContactQuery):
        """Answer every pose of ``query``: returns (BatchContactResult, model version)."""
        model, simulator = self._snapshot()
        batch = simulator.query_batch(query.mesh, list(query.poses), query.approach,
                                      query.torque_centre)
        return batch, int(model.version)
