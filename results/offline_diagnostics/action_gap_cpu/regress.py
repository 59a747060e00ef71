import warnings, numpy as np, jax, jax.numpy as jnp, optax, flax.linen as nn
from offline import collect
from offline import data as odata
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    import sys; ds=collect.collect_recipe("three_link/env3","expert",int(sys.argv[1]),seed=0)
tr, te = odata.split_by_episode(ds, 0.9, jax.random.PRNGKey(0))
L=ds.metadata["observation_layout"]; print(L)
def cols(names): return np.concatenate([np.arange(*L[n]) for n in names])
class M(nn.Module):
    @nn.compact
    def __call__(self,x):
        for _ in range(3): x=nn.relu(nn.Dense(256)(x))
        return nn.Dense(3)(x)
def run(names, steps=20000):
    c=cols(names); X=np.asarray(tr.observations)[:,c]; Y=np.asarray(tr.actions); Xt=np.asarray(te.observations)[:,c]; Yt=np.asarray(te.actions)
    mu,sd=X.mean(0),X.std(0)+1e-6; X=jnp.asarray((X-mu)/sd); Xt=(Xt-mu)/sd; Yj=jnp.asarray(Y)
    m=M(); p=m.init(jax.random.PRNGKey(0),X[:1]); opt=optax.adam(5e-4); s=opt.init(p)
    @jax.jit
    def step(p,s,k):
        i=jax.random.randint(k,(256,),0,X.shape[0])
        l,g=jax.value_and_grad(lambda p: jnp.mean(jnp.sum((m.apply(p,X[i])-Yj[i])**2,-1)))(p)
        u,s=opt.update(g,s); return optax.apply_updates(p,u),s,l
    k=jax.random.PRNGKey(1)
    for t in range(steps):  # noqa
        k,kk=jax.random.split(k); p,s,l=step(p,s,kk)
    e=lambda X,Y: float(np.mean(np.sum((np.asarray(m.apply(p,X))-Y)**2,-1)))
    print(names, "train", round(e(X,Y),3), "held-out", round(e(Xt,Yt),3), "var", round(float(Yt.var(0).sum()),3), flush=True)


run(["sin_q","cos_q","qd","goal_minus_x","obstacle_vectors","obstacles"])
