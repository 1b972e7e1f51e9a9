#!/usr/bin/env python3
# Per-material accuracy of point clouds (docs/geometry.md, "Photometric refinement at export"): each point is given
# the material of truth/materials.tif under it (GDAL's gdallocationinfo), the cloud is split into one binary PLY per
# material (the input's header and rows, unchanged), and `msnerf compare-cloud` measures each part against the whole
# ground-truth cloud: median distance to the truth's local surface, median signed elevation offset, RMSE planar /
# vertical. Distances are 3D, so the ground under a crown's overhang (which the top-down material map calls
# "crown") counts as the ground it is, which a height-minus-DSM comparison (this tool before 2026-11-27) did not.
# Usage: tools/cloud-by-material.py CLOUD.ply...   (DATA=geometry-report-output/data: the simulation, MSNERF=./target/release/msnerf)
import collections, json, os, struct, subprocess, sys, tempfile

DATA = os.environ.get('DATA', 'geometry-report-output/data')
MSNERF = os.environ.get('MSNERF', './target/release/msnerf')


def class_names():
    """{class: name} from materials.tif's band description ('classes 1=asphalt 2=bark ...')."""
    info = json.loads(subprocess.run(['gdalinfo', '-json', f'{DATA}/truth/materials.tif'], capture_output=True,
                                     text=True, check=True).stdout)
    words = info['bands'][0].get('description', '').split()
    return {int(k): v for k, _, v in (w.partition('=') for w in words if '=' in w)}


FMT = {'double': 'd', 'float': 'f', 'uchar': 'B', 'int': 'i', 'uint': 'I', 'ushort': 'H', 'short': 'h'}


def split(path, tmp):
    """Writes tmp/<class>.ply per material; returns {class: path}."""
    with open(path, 'rb') as f:
        header, props, n = [], [], 0
        while True:
            line = f.readline()
            if not line:
                sys.exit(f'{path}: no end_header')
            header.append(line)
            s = line.decode('latin1').strip()
            if s.startswith('format') and 'binary_little_endian' not in s:
                sys.exit(f'{path}: only binary little-endian PLY is read')
            if s.startswith('element vertex'):
                n = int(s.split()[2])
            elif s.startswith('property'):
                props.append(s.split()[1:])
            elif s == 'end_header':
                break
        if [p[1] for p in props[:3]] != ['x', 'y', 'z'] or props[0][0] != 'double':
            sys.exit(f'{path}: expected double x, y, z first')
        size = struct.calcsize('<' + ''.join(FMT[p[0]] for p in props))
        data = f.read(n * size)
    xy = [struct.unpack_from('<dd', data, i * size) for i in range(n)]
    query = '\n'.join(f'{x} {y}' for x, y in xy)
    out = subprocess.run(['gdallocationinfo', '-valonly', '-geoloc', f'{DATA}/truth/materials.tif'],
                         input=query, capture_output=True, text=True, check=True).stdout.split('\n')
    rows = collections.defaultdict(list)
    for i in range(n):
        try:
            rows[int(float(out[i]))].append(data[i * size:(i + 1) * size])
        except (ValueError, IndexError):
            pass  # outside the material map
    parts = {}
    for c, r in rows.items():
        parts[c] = os.path.join(tmp, f'{c}.ply')
        with open(parts[c], 'wb') as g:
            for line in header:
                if line.decode('latin1').startswith('element vertex'):
                    line = f'element vertex {len(r)}\n'.encode()
                g.write(line)
            g.write(b''.join(r))
    return parts


NAMES = class_names()
for path in sys.argv[1:]:
    print(f'== {path}: material, points, median distance, median signed dz, RMSE planar / vertical (m)')
    with tempfile.TemporaryDirectory() as tmp:
        for c, part in sorted(split(path, tmp).items()):
            r = json.loads(subprocess.run([MSNERF, 'compare-cloud', '--pred', part, '--ref',
                                           f'{DATA}/ground_truth.ply', '--json'],
                                          capture_output=True, text=True, check=True).stdout)
            a, p, s = r['accuracy'], r['position'], r['standard']
            print(f"  {NAMES.get(c, c):10s} {a['count']:7d} {a['median']:6.3f} {p['median_signed_dz']:+7.3f} "
                  f"{s['planar']['rmse']:5.2f} / {s['vertical']['rmse']:.2f}")
