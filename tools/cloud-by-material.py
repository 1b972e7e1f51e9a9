#!/usr/bin/env python3
# Per-material heights of point clouds (docs/geometry.md, "Photometric refinement"): every 5th point's z minus the
# true DSM at its position, grouped by truth/materials.tif (queried with GDAL's gdallocationinfo). Usage:
# tools/cloud-by-material.py CLOUD.ply... (TRUTH=geometry-report-output/data/truth by default)
import struct, sys, subprocess, collections
import os
T=os.environ.get('TRUTH', 'geometry-report-output/data/truth')
def read_ply(path, step=5):
    f=open(path,'rb'); props=[]; n=0
    while True:
        line=f.readline().decode('latin1').strip()
        if line.startswith('element vertex'): n=int(line.split()[2])
        elif line.startswith('property'): props.append(line.split()[1:])
        elif line=='end_header': break
    fmt={'double':'d','float':'f','uchar':'B','int':'i','uint':'I','ushort':'H','short':'h'}
    st='<'+''.join(fmt[p[0]] for p in props); sz=struct.calcsize(st)
    data=f.read(n*sz); pts=[]
    for i in range(0,n,step):
        v=struct.unpack_from(st,data,i*sz); pts.append(v[:3])
    return pts
def query(tif, pts):
    inp='\n'.join(f'{x} {y}' for x,y,z in pts)
    out=subprocess.run(['gdallocationinfo','-valonly','-geoloc',tif],input=inp,capture_output=True,text=True).stdout.split('\n')
    return out[:len(pts)]
for path in sys.argv[1:]:
    pts=read_ply(path)
    cls=query(f'{T}/materials.tif',pts); dsm=query(f'{T}/dsm.tif',pts)
    by=collections.defaultdict(list)
    for p,c,d in zip(pts,cls,dsm):
        try: by[int(float(c))].append(p[2]-float(d))
        except: pass
    res=[]
    for c in sorted(by):
        v=sorted(by[c]); m=v[len(v)//2]; a=sorted(abs(x) for x in v)[len(v)//2]
        res.append(f'{c}:{m:+.2f}/{a:.2f}({len(v)})')
    print(path.split('/')[-2:], ' '.join(res))
