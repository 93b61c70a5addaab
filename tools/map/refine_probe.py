# Prototype of the photometric refinement (SPEC.md §10.3) used on 2026-12-06 to choose its rule and
# parameters on the validation scenes, kept so that the table in docs/map/results.md can be re-run.
# It refines an existing `map` run's keyframe depth (`depth_tv.pfm`, level 1) into a copy of the run's
# folder; `densefeat map --refine off` on that copy then re-fuses it (the keyframe folders are reused:
# the fingerprint of a run made before `--refine` existed is that of `--refine off`). Differences
# from the Rust implementation: scipy's `reflect` borders for the window sums, half-pixel-centred
# upsampling, and the level-1 value set to the mean of its 2x2 block of refined values.
#
#   python3 tools/map/refine_probe.py SRC_RUN_SCENE DST_RUN_SCENE SEQUENCE CURVATURE RADIUS_BINS \
#       FRAMES WINDOW BEST_FRACTION sad|zncc
# prototype: photometric 1-D refinement of map keyframe depth, write depth_tv.pfm into a copy
import numpy as np, sys, json, os, glob, shutil
from PIL import Image
from scipy.ndimage import uniform_filter, map_coordinates
src, dst, seq, thr, rng, nlive, patch = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5]), int(sys.argv[6]), int(sys.argv[7])
best=float(sys.argv[8]) if len(sys.argv)>8 else 1.0
mode=sys.argv[9] if len(sys.argv)>9 else 'sad'
DRHO=(1/0.4-1/10)/127
K = np.loadtxt(f'{seq}/K.txt'); P = np.loadtxt(f'{seq}/poses.txt').reshape(-1,4,4)
files = sorted(glob.glob(f'{seq}/images/*'))
def img(i): return np.asarray(Image.open(files[i]).convert('RGB'),dtype=np.float64)
def rpfm(p):
    f=open(p,'rb'); f.readline(); w,h=map(int,f.readline().split()); f.readline()
    return np.frombuffer(f.read(),dtype='<f4').reshape(h,w)[::-1].astype(np.float64)
def wpfm(p,a):
    h,w=a.shape
    with open(p,'wb') as f:
        f.write(b'Pf\n'+f'{w} {h}\n'.encode()+b'-1.0\n'); f.write(np.ascontiguousarray(a[::-1]).astype('<f4').tobytes())
if os.path.exists(dst): shutil.rmtree(dst)
shutil.copytree(src,dst); 
for f in ['map.json','mesh.ply','mesh.png']:
    if os.path.exists(f'{dst}/{f}'): os.remove(f'{dst}/{f}')
Kinv=np.linalg.inv(K)
for kd in sorted(glob.glob(f'{dst}/keyframes/kf_*')):
    kf=int(kd.split('_')[-1]); meta=json.load(open(f'{kd}/keyframe.json'))
    d1=rpfm(f'{kd}/depth_tv.pfm'); h1,w1=d1.shape
    I0=img(kf); H,W,_=I0.shape
    s=W//w1
    rho1=np.where(d1>0,1/np.maximum(d1,1e-9),0)
    YY,XX=np.meshgrid((np.arange(H)+0.5)/s-0.5,(np.arange(W)+0.5)/s-0.5,indexing='ij')
    rho0=map_coordinates(rho1,[YY,XX],order=1,mode='nearest')
    live=meta['live_frames']; sel=live[::max(1,int(np.ceil(len(live)/nlive)))]
    v,u=np.mgrid[0:H,0:W].astype(np.float64); rays=np.stack([u,v,np.ones_like(u)],-1)@Kinv.T
    lives=[(img(j),np.linalg.inv(P[j])@P[kf]) for j in sel]
    offs=np.linspace(-rng,rng,33); C=np.zeros((len(offs),H,W))
    for a,o in enumerate(offs):
        X=rays*(1/np.maximum(rho0+o*DRHO,1e-3))[...,None]
        per=np.full((len(lives),H,W),np.inf)
        for i,(Ij,T) in enumerate(lives):
            Xc=X@T[:3,:3].T+T[:3,3]; z=Xc[...,2]; uv=Xc@K.T; uu=uv[...,0]/z; vv=uv[...,1]/z
            ok=(z>0.05)&(uu>=0)&(uu<=W-1)&(vv>=0)&(vv<=H-1)
            w=np.stack([map_coordinates(Ij[...,c],[vv,uu],order=1,mode='nearest') for c in range(3)],-1)
            okf=uniform_filter(ok.astype(float),patch)>0.999
            if mode=='sad':
                per[i]=np.where(okf,uniform_filter(np.where(ok,np.abs(w-I0).sum(-1),0),patch),np.inf)
            else:
                wg=w.mean(-1); Ig=I0.mean(-1); U=lambda x: uniform_filter(x,patch)
                mw,mi=U(wg),U(Ig); cov=U(wg*Ig)-mw*mi; vw=U(wg*wg)-mw*mw; vi=U(Ig*Ig)-mi*mi
                ncc=cov/np.sqrt(np.maximum(vw,1e-6)*np.maximum(vi,1e-6))
                per[i]=np.where(okf&(vi>1.0),1-ncc,np.inf)
        per.sort(0); nseen=np.isfinite(per).sum(0); kb=np.maximum(1,np.ceil(best*nseen)).astype(int)
        cs=np.cumsum(np.where(np.isfinite(per),per,0),0)
        C[a]=np.where(nseen>=max(2,len(lives)//2), np.take_along_axis(cs,(kb-1)[None],0)[0]/kb, np.inf)
    k=np.argmin(C,0); kk=np.clip(k,1,len(offs)-2)
    g=lambda j: np.take_along_axis(C,j[None],0)[0]
    c0,c1,c2=g(kk-1),g(kk),g(kk+1)
    with np.errstate(invalid='ignore',divide='ignore'):
        den=c0-2*c1+c2; step=offs[1]-offs[0]
        sub=np.where((den>0)&np.isfinite(den),0.5*(c0-c2)/np.where(den>0,den,1),0)
        ok=(k>0)&(k<len(offs)-1)&np.isfinite(c1)&np.isfinite(den)&(den/step**2>thr)
    rr=np.where(ok,rho0+(offs[kk]+np.clip(sub,-.5,.5)*step)*DRHO,rho0)
    # back to level-1 grid: mean of the s x s block
    r1=rr.reshape(h1,s,w1,s).mean((1,3))
    out=np.where(d1>0,1/np.maximum(r1,1e-9),0)
    wpfm(f'{kd}/depth_tv.pfm',out)
    print(kd, 'refined frac', ok.mean())
