"""Writes a two-robot depthcal cell from the 7-Scenes frames in ../shared/data/7scenes-rgbd-tsdf-fusion: even
frames are robot "left", odd frames robot "right", with made-up hand-eyes and T_base1_base2 = (1.1, 0.5, 0 m,
2.6 rad about z). A hand-written cell.toml (matrix pose files, no [priors], no ground_truth.json).

usage: python3 tools/seven_scenes_two_robot_cell.py OUT_DIR PERTURBATION
  PERTURBATION 0: the true hand-eyes in cell.toml; 1: both hand-eyes about 4 mm / 1.5 deg off.
Run from the repository root. Prints the true T_base1_base2 translation."""
import math, os, glob, shutil, json, sys
D="../shared/data/7scenes-rgbd-tsdf-fusion/frames"
O=sys.argv[1]; pert=float(sys.argv[2])  # hand-eye perturbation scale (1 = 4 mm / 1.5 deg)
def rot(ax, ang):
    x,y,z = ax; n = math.sqrt(x*x+y*y+z*z); x,y,z = x/n,y/n,z/n
    c,s = math.cos(ang), math.sin(ang); C = 1-c
    return [[c+x*x*C, x*y*C-z*s, x*z*C+y*s],[y*x*C+z*s, c+y*y*C, y*z*C-x*s],[z*x*C-y*s, z*y*C+x*s, c+z*z*C]]
def T(R,t): return [R[0]+[t[0]],R[1]+[t[1]],R[2]+[t[2]],[0,0,0,1]]
def mul(A,B): return [[sum(A[i][k]*B[k][j] for k in range(4)) for j in range(4)] for i in range(4)]
def inv(A):
    R=[[A[j][i] for j in range(3)] for i in range(3)]; t=[A[i][3] for i in range(3)]
    return T(R,[-sum(R[i][k]*t[k] for k in range(3)) for i in range(3)])
X=[T(rot([0.2,-0.3,1],1.5),[0.03,-0.02,0.1]), T(rot([-0.1,0.2,1],-1.4),[-0.025,0.015,0.09])]
Xc=[mul(X[0],T(rot([1,2,0.5],math.radians(1.5*pert)),[0.004*pert,0,0])), mul(X[1],T(rot([-1,0.3,2],math.radians(1.2*pert)),[0,-0.003*pert,0.002*pert]))]
B1W=T(rot([0,0,1],0.5),[0.4,-0.2,0.75])
B1B2=T(rot([0,0,1],2.6),[1.1,0.5,0.0])
BW=[B1W, mul(inv(B1B2),B1W)]
ids=sorted(os.path.basename(p)[6:12] for p in glob.glob(D+"/frame-*.depth.png"))
os.makedirs(O, exist_ok=True)
toml='format = "depthcal-cell/1"\nreference = "left"\n'
for k,name in enumerate(["left","right"]):
    os.makedirs(f"{O}/{name}/depth", exist_ok=True)
    json.dump({"fx":585.0,"fy":585.0,"ppx":320.0,"ppy":240.0,"coeffs":[0,0,0,0,0],"model":"brown_conrady","width":640,"height":480,"depth_scale":0.001}, open(f"{O}/{name}/intrinsics.json","w"))
    f=open(f"{O}/{name}/poses.csv","w"); f.write("frame,"+",".join(f"m{i}{j}" for i in range(4) for j in range(4))+"\n")
    for i,id in enumerate(ids):
        if i%2!=k: continue
        W=[[float(v) for v in l.split()] for l in open(f"{D}/frame-{id}.pose.txt") if l.strip()]
        E=mul(mul(BW[k],W),inv(X[k]))
        f.write(id+","+",".join(repr(v) for r in E for v in r)+"\n")
        shutil.copy(f"{D}/frame-{id}.depth.png", f"{O}/{name}/depth/{id}.png")
    he=", ".join(repr(v) for r in Xc[k] for v in r)
    toml+=f'\n[[robot]]\nname = "{name}"\nposes = "{name}/poses.csv"\npose_format = "matrix"\nintrinsics = "{name}/intrinsics.json"\nhand_eye = [{he}]\ndepth = "{name}/depth/{{frame}}.png"\n'
open(f"{O}/cell.toml","w").write(toml)
t=B1B2
print("truth T_base1_base2 t=", [round(t[i][3],4) for i in range(3)])
