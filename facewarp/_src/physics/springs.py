"""Point springs a solver stage adds to the tissue energy (muscles, supports, contact): :class:`Springs`."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Springs"]


@dataclass(eq=False)
class Springs:
    """Point springs a solver stage adds to the tissue energy (muscles, supports), on the device.

    Two kinds, by whether :attr:`axis` is given:

    * distance springs ``E = 1/2 k (|p - x| - l0)^2`` (the muscle springs of Eq. 6.4.1 with the
      fibre cosine folded into ``k`` for the step);
    * axis springs ``E = 1/2 k ((x - p) . a)^2`` (a sliding support along the unit axis a).

    With :attr:`one_sided` the springs only push (contact, :mod:`facewarp._src.physics.contact`):

    * axis: ``E = 1/2 k min(0, (x - p) . a)^2``, a half-space ``(x - p) . a >= 0`` the node may
      not leave (p on the obstacle's surface, a its outward unit normal);
    * distance: ``E = 1/2 k min(0, |x - p| - l0)^2``, a ball of radius l0 about p the node may
      not enter (the eyeball).

    Both are C1 (the force vanishes continuously at the surface); their Hessian is ``k a a^T``
    (``k n n^T``, ``n = (x - p) / |x - p|``) where the spring is compressed and 0 elsewhere.

    A stage that has springs fills them in its ``prepare`` (once per implicit step); the arrays
    stay allocated, so a captured frame keeps reading the same buffers.
    """

    node: object
    """Tissue node of each spring, shape (k,), int32."""
    point: object
    """The spring's other end p [m], shape (k,), wp.vec3."""
    stiffness: object
    """Stiffness k [N/m], shape (k,), float32."""
    rest_length: object = None
    """Rest length l0 [m] of distance springs, shape (k,), float32 (None for axis springs)."""
    axis: object = None
    """Unit axis a of axis springs, shape (k,), wp.vec3 (None for distance springs)."""
    one_sided: bool = False
    """Contact springs that only push (see the class doc); a stage sets it once."""

    @property
    def count(self) -> int:
        return int(self.node.shape[0])

