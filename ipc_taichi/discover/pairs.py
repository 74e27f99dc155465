"""Effects whose signatures overlap (:data:`DEGENERATE`: refitted together) and
what tells them apart (:data:`SEPARATION`: reported with the alternatives).
Names are those of :data:`~.effects.EFFECTS`; a new effect need not be here.
"""

__all__ = ["DEGENERATE", "SEPARATION"]

# Pairs whose signatures overlap: when one of them is a candidate and the
# other is already in the model, the candidate is fitted together with the
# partner's parameters (a joint refit), so neither is dropped for having been
# fitted with the other's value frozen.
DEGENERATE = (
    frozenset({"charge_diffusion", "brighter_fatter"}),
    frozenset({"anisotropic_ipc", "diagonal_ipc"}),
    frozenset({"charge_diffusion", "diagonal_ipc"}),
    frozenset({"classical_nonlinearity", "reciprocity_failure"}),
    frozenset({"brighter_fatter", "classical_nonlinearity"}),
    frozenset({"flat_field", "excess_read_noise"}),
)

# What tells near-degenerate effects apart (reported with the alternatives).
SEPARATION = {
    frozenset({"charge_diffusion", "diagonal_ipc"}):
        "diffusion also feeds the 4 nearest neighbours (more than the diagonals) and acts "
        "before shot noise; diagonal IPC feeds only the diagonals and scales with the law",
    frozenset({"charge_diffusion", "brighter_fatter"}):
        "diffusion moves a fixed fraction at every signal; brighter-fatter moves a fraction "
        "that grows with the charge already collected (compare stacks binned by signal)",
    frozenset({"brighter_fatter", "diagonal_ipc"}):
        "brighter-fatter feeds the nearest neighbours and grows with signal; diagonal IPC "
        "feeds the diagonals",
    frozenset({"charge_diffusion", "anisotropic_ipc"}):
        "diffusion is isotropic with a fixed fraction and a small diagonal part; a rescaled "
        "IPC geometry follows the law's signal dependence and has no diagonal part",
    frozenset({"brighter_fatter", "anisotropic_ipc"}):
        "brighter-fatter grows with signal; a rescaled IPC geometry follows the law",
    frozenset({"brighter_fatter", "classical_nonlinearity"}):
        "brighter-fatter conserves charge (neighbours gain what the peak loses) and leaves "
        "flat fields flat; non-linearity loses signal, flat patches included",
    frozenset({"brighter_fatter", "signal_dependent_ipc"}):
        "both change the neighbour fraction with signal; brighter-fatter acting on the "
        "arriving charge, before shot noise, makes the neighbours' variance grow with what "
        "they receive, a coupling does not (compare evidence_with_variance: positive for "
        "brighter-fatter when it acts before shot noise; a flow computed from the collected "
        "charge is, in its noise, a coupling)",
    frozenset({"signal_dependent_ipc", "anisotropic_ipc"}):
        "a signal-dependent law changes the coupling with signal in both directions; "
        "anisotropy changes it by direction at every signal",
    frozenset({"second_neighbor_ipc", "charge_diffusion"}):
        "diffusion feeds the nearest neighbours first; second-neighbour IPC skips them",
    frozenset({"classical_nonlinearity", "reciprocity_failure"}):
        "non-linearity lowers the response at high signal, after IPC; reciprocity failure "
        "raises it, logarithmically, before shot noise",
    frozenset({"dark_current", "reciprocity_failure"}):
        "dark current adds the same charge everywhere; reciprocity failure scales with signal",
    frozenset({"flat_field", "excess_read_noise"}):
        "a response map adds variance growing as signal squared and repeating pixel by pixel "
        "across pairs; excess read noise is the same at every signal",
}
