#!/usr/bin/env python3
"""Renders the val views of a Mitsuba 3 scene written by `fipt-train export --format mitsuba` and
scores them against reference images.

    render_export.py OUT/scene.xml --out DIR [--views 0,3] [--spp 64] [--scale 2]
                     [--reference FOLDER]... [--variant scalar_rgb] [--bsdf principled|fipt]

Writes DIR/NNN.exr (linear radiance) per view and prints one JSON object. With --reference (a
folder of fipt's image names, NNN_0001.exr: a scene's val/Image photos, or a `render` output's
val/Image; repeatable), it holds each view's PSNR on tone-mapped images, clip(x, 0, 1)^(1/2.2), as fipt scores
re-renders, and the PSNR of each reference's mean colour as a constant image (the trivial
predictor). --scale K renders at 1/K of the size and box-filters the references to match.
"""
import argparse
import json
import os
import re
import sys

import numpy as np


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('scene')
    p.add_argument('--out', required=True)
    p.add_argument('--views', default=None, help='comma-separated view indices (default all)')
    p.add_argument('--spp', type=int, default=64)
    p.add_argument('--max-depth', type=int, default=7)
    p.add_argument('--scale', type=int, default=1)
    p.add_argument('--reference', action='append', default=[],
                   help='a folder of NNN_0001.exr images to score against (repeatable)')
    p.add_argument('--variant', default='scalar_rgb')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--bsdf', choices=['principled', 'fipt'], default='principled',
                   help="fipt: replace the export's principled BSDF by fipt's own (fipt_bsdf.py)")
    a = p.parse_args()

    llvm = '/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1'
    if a.variant.startswith('llvm') and 'DRJIT_LIBLLVM_PATH' not in os.environ and os.path.exists(llvm):
        os.environ['DRJIT_LIBLLVM_PATH'] = llvm
    import mitsuba as mi
    mi.set_variant(a.variant)
    folder = os.path.dirname(os.path.abspath(a.scene))
    xml = open(a.scene).read()
    if a.scale > 1:
        def shrink(m):
            return f'<integer name="{m.group(1)}" value="{int(m.group(2)) // a.scale}"/>'
        xml = re.sub(r'<integer name="(width|height)" value="(\d+)"/>', shrink, xml)
    if a.bsdf == 'fipt':
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        import fipt_bsdf
        fipt_bsdf.register()
        xml = xml.replace('type="principled"', 'type="fipt"')
        xml = xml.replace('<float name="specular" value="0.5"/>', '')
    mi.file_resolver().prepend(folder)
    scene = mi.load_string(xml, spp=str(a.spp), max_depth=str(a.max_depth))
    sensors = scene.sensors()
    ids = [s.id() for s in sensors]
    views = range(len(sensors)) if a.views is None else [int(v) for v in a.views.split(',')]
    os.makedirs(a.out, exist_ok=True)
    # The references are read before any render: Mitsuba 3.9.1 hangs reading an EXR after one.
    refs = {(r, k): np.array(mi.Bitmap(os.path.join(r, f'{k:03d}_0001.exr')), dtype=np.float32)[..., :3]
            for r in a.reference for k in views}
    tone = lambda x: np.clip(x, 0.0, 1.0) ** (1.0 / 2.2)
    psnr = lambda x, y: float(-10.0 * np.log10(max(np.mean((tone(x) - tone(y)) ** 2), 1e-10)))
    rows = []
    for k in views:
        img = np.array(mi.render(scene, sensor=sensors[k], spp=a.spp, seed=a.seed + k))[..., :3]
        mi.util.write_bitmap(os.path.join(a.out, f'{k:03d}.exr'), img)
        row = {'view': k, 'sensor': ids[k], 'size': [img.shape[1], img.shape[0]]}
        for r in a.reference:
            ref = refs[(r, k)]
            s = a.scale
            h, w = img.shape[:2]
            if ref.shape[0] != h * s or ref.shape[1] != w * s:
                sys.exit(f'{r}: view {k} is {ref.shape[1]}x{ref.shape[0]}, not {w * s}x{h * s}')
            ref = ref.reshape(h, s, w, s, 3).mean(axis=(1, 3))
            row.setdefault('psnr', {})[r] = psnr(img, ref)
            row.setdefault('trivial_psnr', {})[r] = psnr(np.broadcast_to(ref.mean(axis=(0, 1)), ref.shape), ref)
        rows.append(row)
    out = {'scene': a.scene, 'variant': a.variant, 'bsdf': a.bsdf, 'spp': a.spp, 'scale': a.scale, 'views': rows}
    out['mean_psnr'] = {r: float(np.mean([v['psnr'][r] for v in rows])) for r in a.reference}
    out['mean_trivial_psnr'] = {r: float(np.mean([v['trivial_psnr'][r] for v in rows]))
                                for r in a.reference}
    print(json.dumps(out))


if __name__ == '__main__':
    main()
