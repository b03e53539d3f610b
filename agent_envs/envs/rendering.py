"""Matplotlib rendering of the swarm envs, kept out of the stepping hot path.

The renderer records the path-mean positions E x^n (a copy of (N, d) per step, only when a
render mode is set) and draws on demand:

- d = 1: every agent's mean position against time up to now, a dot at its current position (so
  the first frame, at t = 0, shows the initial positions), the target as a dashed line;
- d >= 2: a scatter of the first two coordinates at the current time, the target as a cross.

``"rgb_array"`` draws with the Agg canvas on a private `Figure` (no pyplot state) and returns
a uint8 array (H, W, 3). ``"human"`` draws in a pyplot window and pauses 1 / render_fps; with a
non-interactive backend (Agg, as in CI) it draws nothing and returns None.
"""

from __future__ import annotations

from typing import Any

import numpy as np

RENDER_MODES = ("human", "rgb_array")


def check_render_mode(render_mode: Any) -> str | None:
    """Return `render_mode` if it is None or one of RENDER_MODES, else raise ValueError."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be None or one of {RENDER_MODES}, got {render_mode!r}")
    return render_mode


def _backend_is_interactive() -> bool:
    import matplotlib

    backend = matplotlib.get_backend().lower()
    try:
        from matplotlib.backends import BackendFilter, backend_registry

        interactive = backend_registry.list_builtin(BackendFilter.INTERACTIVE)
    except ImportError:  # matplotlib < 3.9
        from matplotlib import rcsetup

        interactive = rcsetup.interactive_bk
    return backend in {b.lower() for b in interactive}


class SwarmRenderer:
    """Records path-mean positions and draws them (see the module docstring)."""

    def __init__(
        self,
        render_mode: str,
        horizon: float,
        fps: int,
        size: tuple[int, int] = (640, 400),
        dpi: int = 80,
    ) -> None:
        self.render_mode = check_render_mode(render_mode)
        self.horizon = horizon
        self.fps = fps
        self.size = size
        self.dpi = dpi
        self._times: list[float] = []
        self._positions: list[np.ndarray] = []
        self._target: np.ndarray | None = None
        self._figure: Any = None

    def reset(self, time: float, mean_positions: np.ndarray, target: np.ndarray) -> None:
        """Start a new history at the initial state."""
        self._times = [time]
        self._positions = [np.array(mean_positions, copy=True)]
        self._target = np.array(target, copy=True)

    def record(self, time: float, mean_positions: np.ndarray) -> None:
        """Append the state after a step."""
        self._times.append(time)
        self._positions.append(np.array(mean_positions, copy=True))

    def _draw(self, figure: Any) -> None:
        figure.clear()
        ax = figure.add_subplot(1, 1, 1)
        if not self._positions:
            ax.set_title("swarm (call reset() first)")
            return
        history = np.stack(self._positions)  # (n + 1, N, d)
        target = self._target
        times = np.asarray(self._times)
        if history.shape[-1] == 1:
            ax.plot(times, history[..., 0], color="tab:blue", linewidth=0.6, alpha=0.6)
            # the agents now, as dots at the front of their traces: at t = 0 (no trace yet)
            # the frame shows the initial positions instead of empty axes
            now = history[-1, :, 0]
            ax.scatter(
                np.full(now.shape, times[-1]), now, s=12, color="tab:blue", label="agents", zorder=3
            )
            ax.axhline(target[0], color="tab:red", linestyle="--", label="target")
            ax.set_xlim(-0.03 * self.horizon, self.horizon)  # room for the dots at t = 0
            ax.set_xlabel("t")
            ax.set_ylabel("E x_k(t)")
        else:
            now = history[-1]
            ax.scatter(now[:, 0], now[:, 1], s=10, color="tab:blue", label="agents")
            ax.scatter([target[0]], [target[1]], s=80, marker="x", color="tab:red", label="target")
            ax.set_xlabel("x_1")
            ax.set_ylabel("x_2")
            ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"t = {times[-1]:.3f}")
        ax.legend(loc="upper right")

    def render(self) -> np.ndarray | None:
        """A uint8 (H, W, 3) frame for "rgb_array"; draws a window and returns None for "human"."""
        if self.render_mode == "rgb_array":
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            if self._figure is None:
                width, height = self.size
                self._figure = Figure(figsize=(width / self.dpi, height / self.dpi), dpi=self.dpi)
                FigureCanvasAgg(self._figure)
            self._draw(self._figure)
            canvas = self._figure.canvas
            canvas.draw()
            return np.array(canvas.buffer_rgba(), dtype=np.uint8)[..., :3].copy()
        if self.render_mode == "human":
            if not _backend_is_interactive():
                return None
            import matplotlib.pyplot as plt

            if self._figure is None:
                width, height = self.size
                self._figure = plt.figure(figsize=(width / self.dpi, height / self.dpi))
            self._draw(self._figure)
            self._figure.canvas.draw_idle()
            plt.pause(1.0 / self.fps)
        return None

    def __getstate__(self) -> dict[str, Any]:
        """Pickle/deepcopy without the matplotlib figure (its canvas does not survive a copy).

        The recorded history is kept; the copy draws a new figure on its next `render()`.
        """
        state = self.__dict__.copy()
        state["_figure"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def close(self) -> None:
        """Release the figure (safe to call twice)."""
        if self._figure is not None and self.render_mode == "human":
            import matplotlib.pyplot as plt

            plt.close(self._figure)
        self._figure = None
