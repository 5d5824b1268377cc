"""Image files, one module per stage or format; poisoner.formats.poison_file runs them in order.

- read.py      open and fully decode (one ImageFormatError line for every failure)
- png.py, webp.py, tiff.py, heif.py   one writer per format: (bytes, preserved, notes, ...)
  (JPEG's writer is in poisoner.formats, next to the DCT splice it drives in poisoner.jpeg)
- metadata.py  EXIF/XMP/ICC for re-encoded formats: location removed, provenance marker added
- write.py     Pillow helpers: paste the patch, save with only explicit metadata
"""
