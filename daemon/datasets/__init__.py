"""Which dataset a file belongs to and what the dataset holds: the one attribution rule
(dataset.py), its subject masks and corner (subject_masks.py), its folder counted next to its rows
(folder_count.py)."""
