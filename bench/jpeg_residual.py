#!/usr/bin/env python3
"""What a JPEG-coded residual on top of a neural material's decode buys at mip 0: per map, the
source minus the decode (offset by 128, clipped to ±127) coded with cjpeg at several qualities
(4:4:4, optimized Huffman tables), decoded with djpeg and added back; prints the residuals' bytes
as BPPC of mip 0 (over CHANNELS, the material's learned channels) and the mip-0 PSNR over the
maps' RGB channels before and after. JPEG is the codec nmat already decodes per texel (indexed
JPEG, docs/FORMAT.md §11), so this is the cheapest hybrid a random-access decoder could have.

Usage: nmat decode F.nmat -o DECODED && bench/jpeg_residual.py SOURCE_DIR DECODED MAP[,MAP…] CHANNELS
  e.g. bench/jpeg_residual.py dev/stk-eggkart decoded albedo,normal 6
Needs: cjpeg, djpeg (libjpeg-turbo-progs), numpy, pillow.
"""
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image


def load(path):
    return np.asarray(Image.open(path).convert('RGB')).astype(int)


def psnr(src, dec, maps):
    mse = np.mean([((src[m] - dec[m]) ** 2).mean() for m in maps])
    return 10 * np.log10(255 ** 2 / mse)


def main():
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    source, decoded, maps, channels = sys.argv[1], sys.argv[2], sys.argv[3].split(','), int(sys.argv[4])
    src = {m: load(os.path.join(source, m + '.png')) for m in maps}
    dec = {m: load(os.path.join(decoded, m + '.png')) for m in maps}
    h, w = src[maps[0]].shape[:2]
    print(f'decode alone: mip-0 PSNR {psnr(src, dec, maps):.2f} dB')
    with tempfile.TemporaryDirectory() as tmp:
        jpg, back = os.path.join(tmp, 'r.jpg'), os.path.join(tmp, 'b.ppm')
        # Each map's residual written once, coded at every quality.
        ppms = {m: os.path.join(tmp, f'{i}.ppm') for i, m in enumerate(maps)}
        for m, ppm in ppms.items():
            residual = np.clip(src[m] - dec[m], -127, 127) + 128
            Image.fromarray(residual.astype(np.uint8)).save(ppm)
        for quality in (50, 70, 80, 90, 95):
            total, rebuilt = 0, {}
            for m in maps:
                subprocess.run(['cjpeg', '-quality', str(quality), '-sample', '1x1', '-optimize',
                                '-outfile', jpg, ppms[m]], check=True)
                total += os.path.getsize(jpg)
                subprocess.run(['djpeg', '-outfile', back, jpg], check=True)
                rebuilt[m] = np.clip(dec[m] + np.asarray(Image.open(back)).astype(int) - 128, 0, 255)
            print(f'quality {quality}: residual {total} bytes = {total * 8 / (w * h * channels):.4f} '
                  f'BPPC of mip 0, mip-0 PSNR {psnr(src, rebuilt, maps):.2f} dB')


if __name__ == '__main__':
    main()
