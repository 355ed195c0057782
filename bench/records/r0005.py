"""Record 0005 (local subspaces): the ablation none / spatial / temporal / both on a dense
face, clean and at the paper's noise r = 0.03, with the true rotations (as the record's table).

    python -m bench.records.r0005 [--full]

Quick: face 99 x 1,000; ``--full``: 99 x 2,000 and 99 x 8,000 (the record's sizes). Without
the face model the bending sheet (60 x 1,000) stands in. The clean ablation with estimated
rotations is the parameters bench (``python -m bench --full --only parameters``).
"""
from grass_nrsfm_ros.nrsfm import WarmStart
from grass_nrsfm_ros.nrsfm.faces import make_face_sequence
from grass_nrsfm_ros.nrsfm.synthetic import make_sequence
from . import compare

SETTINGS = [('both', {}), ('none', {'spatial': False, 'temporal': False}),
            ('spatial', {'temporal': False}), ('temporal', {'spatial': False})]


def sequences(full):
    """``[(name, Sequence)]``: faces where the model exists, else the bending sheet."""
    try:
        return [(f'face99x{P}', make_face_sequence(n_frames=99, n_points=P))
                for P in ((2000, 8000) if full else (1000,))]
    except FileNotFoundError:
        return [('bending60x1000', make_sequence('bending', 60, 1000))]


def main(argv=None):
    args = compare.parse(argv, __doc__)
    cases, rotations = [], {}
    for name, seq in sequences(args.full):
        clean = [(name, seq.W, seq.S)]
        for case in clean + compare.noisy(clean, 0.03):
            cases.append(case)
            rotations[case[0]] = seq.R
    compare.table(cases, SETTINGS, init=lambda name: WarmStart(R=rotations[name]))


if __name__ == '__main__':
    main()
